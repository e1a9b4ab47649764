"""rtdenoise: deploy real-time Monte Carlo denoisers from PyTorch through ONNX Runtime."""

__version__ = "0.1.0"
