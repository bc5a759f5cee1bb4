"""The built-in per-view products, one module each, registered in specsynth's ``pyproject.toml``
(``specsynth.products``) exactly as another package would register its own; none imports another
(an import-linter contract). See :mod:`specsynth.output_api` for what a product is given."""
