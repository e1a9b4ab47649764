"""blend_kpn: a denoiser family and a filter op that live outside rtdenoise
(rtdenoise's docs/your-own-model.md walks through it)."""
