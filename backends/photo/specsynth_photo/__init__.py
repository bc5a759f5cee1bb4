"""The photo baseline (the paper's BL images) as a specsynth backend plugin: dataset objects
rasterised with OpenGL over real photographs. Importing this package does not import OpenGL."""

from specsynth.plugins import BackendPlugin, Capabilities

from .options import PhotoOptions

PLUGIN = BackendPlugin(
    name="photo",
    default_rank=20,  # specsynth init's choice when several backends are installed
    options=PhotoOptions,
    backend="specsynth_photo.backend:PhotoBackend",
    capabilities=Capabilities(
        # Only the dataset objects are drawn: the annotation engine then uses them alone as occluders.
        draws_scene=False, denoise=False, gpu=False,
        material_channels=frozenset({"base_color"}),
        quality="rasterised: no samples; the preset is ignored",
    ),
    distributions=("pyrender", "scikit-image"),
    # 2: background and augmentation maths without BLAS; 3: pano trigonometry in float64; 4: meshes at
    # one distance drawn in name order (pyrender broke the tie by a set order, run to run)
    revision=4,
    cost=(0.05, 0.0),
    checks="specsynth_photo.checks:checks",  # `specsynth doctor`
    install_hint="pip install -e backends/photo  and apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri",
)

__all__ = ["PLUGIN", "PhotoOptions"]
