"""The canonical frame buffers and their channel counts (design.md s.3): the one table.

Torch-free so that runtime/ and models/ (which imports it) share it.
"""

BUFFER_CHANNELS: dict[str, int] = {
    "color": 3,  # linear HDR radiance, mean of the frame's samples
    "color_b": 3,  # an independent second estimate (Choi24)
    "albedo": 3,
    "normal": 3,  # in [-1, 1]
    "depth": 1,  # linear view depth
    "motion": 2,  # pixels, previous position = current + motion, x right, y down
}
