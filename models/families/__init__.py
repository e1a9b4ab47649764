"""The denoiser families, one module each; each registers its model with `@register_family`.

Found by scanning this package (models.registry), so a new family is one new module here.
"""
