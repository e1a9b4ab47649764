"""Files shipped inside the package: demo checkpoints, ONNX models, sample sequences and
layout presets."""

from __future__ import annotations

from pathlib import Path

ASSETS_DIR = Path(__file__).resolve().parent / "assets"
SEQUENCES_DIR = ASSETS_DIR / "sequences"
MODELS_DIR = ASSETS_DIR / "models"
LAYOUTS_DIR = ASSETS_DIR / "layouts"  # layout presets (TOML), runtime/sequences/layouts.py


def sample_sequences() -> list[Path]:
    """The bundled sample sequences, one folder each, sorted by name."""
    if not SEQUENCES_DIR.is_dir():
        return []
    return sorted(p for p in SEQUENCES_DIR.iterdir() if p.is_dir())


def demo_names() -> list[str]:
    """The shipped demo models as `demo:<name>` specs (a family, or `<family>-small`), sorted."""
    if not MODELS_DIR.is_dir():
        return []
    return sorted(f"demo:{p.stem}" for p in MODELS_DIR.glob("*.onnx"))


def demo_model(family: str, suffix: str) -> Path:
    """Path of the shipped demo model `demo:<family>` (suffix '.pt' or '.onnx')."""
    path = MODELS_DIR / f"{family}{suffix}"
    if not path.is_file():
        available = ", ".join(demo_names()) or "none"
        raise FileNotFoundError(
            f"no shipped demo model 'demo:{family}' ({path.name}); available: {available}"
        )
    return path
