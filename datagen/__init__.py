"""rtdenoise.datagen: render denoising data with Mitsuba 3 (optional extra `[data]`).

Modules: `scene` (random scene descriptions -> Mitsuba scenes), `camera` (pinhole
model and camera paths, numpy), `features` (AOVs -> canonical buffers and their
conventions, numpy), `render` (one sequence -> canonical EXR folder),
`validate` (motion-vector check by warping references, numpy), `variant`
(scalar_rgb / llvm_ad_rgb selection). CLI: `denoise-render` (rtdenoise.cli.render).
Only `render`, `scene.build_scene` and `variant` need mitsuba.
"""
