"""viewer: a take or a prediction as a face (pyvista, offscreen), as curves, as video, live in Unreal
(Live Link packets), and a dataset as one HTML page. Imports every other stage; none imports it."""

# capture, imported first, guards the imports of a stage command against Ctrl-C (capture.import_guard); the
# guard ends once the command's own module (cli.py) has imported, after this package's imports.
import capture.import_guard  # noqa: F401  # isort: skip

from .face import FaceModel, Part, builtin_face, weights_from_values
from .gltf import arkit_channel, load_gltf, write_glb
from .plot import plot_curves
from .probe import RenderUnavailable, probe
from .render import Animation, FaceRenderer, load_animation, render_frame, write_mp4
from .report import write_report
from .stream import stream_take

__all__ = [
    "Animation",
    "FaceModel",
    "FaceRenderer",
    "Part",
    "RenderUnavailable",
    "arkit_channel",
    "builtin_face",
    "load_animation",
    "load_gltf",
    "plot_curves",
    "probe",
    "render_frame",
    "stream_take",
    "weights_from_values",
    "write_glb",
    "write_mp4",
    "write_report",
]
