"""rtdenoise's denoiser families, one module each; each registers its model with
`@register_family` and is declared an entry point of group `rtdenoise.families` in
pyproject.toml (models.registry), the same path as a user's family (docs/your-own-model.md).
"""
