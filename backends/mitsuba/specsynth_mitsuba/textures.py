"""A product texture: Mitsuba has none, and base colour = constant x vertex colour x texture.

The class must derive from the *active variant's* ``mi.Texture``, so it is made (and registered
with Mitsuba's plugin registry) after ``mi.set_variant``.
"""

from __future__ import annotations

PRODUCT = "specsynth_product"


def register_product_texture(mi) -> None:
    class ProductTexture(mi.Texture):
        """eval = a(si) * b(si); both children must be textures (not plain colours)."""

        def __init__(self, props):
            super().__init__(props)
            self.a = props["a"]
            self.b = props["b"]

        def eval(self, si, active=True):
            return self.a.eval(si, active) * self.b.eval(si, active)

        def mean(self):
            # exact only for uncorrelated factors; Mitsuba uses it for sampling heuristics only
            return self.a.mean() * self.b.mean()

        def is_spatially_varying(self):
            return True

        def traverse(self, callback):
            callback.put("a", self.a, mi.ParamFlags.NonDifferentiable)
            callback.put("b", self.b, mi.ParamFlags.NonDifferentiable)

    mi.register_texture(PRODUCT, lambda props: ProductTexture(props))
