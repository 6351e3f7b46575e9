"""Scene input: read a scene folder (NeRF-synthetic or COLMAP) into a ``Scene``, validate it, and save /
load the ``scene`` step's artifact that every downstream step reads; ``masking`` gives the training views'
object masks (provided ones validated, else GrabCut or a local ONNX model); ``auto_mask`` the auto masks
(u2netp from ``salient_weights``, post-processing from ``mask_post``, the user's box from ``object_hint``).

* ``load_scene(path, views=0, max_size=0) -> Scene`` (raises ``SceneError`` at the first problem)
* ``validate_scene(path, views=0) -> ValidationReport`` (collects every problem; ``.ok``, ``.summary()``)
* ``save_scene_artifact(scene, out_dir)`` / ``load_scene_artifact(dir) -> Scene``
"""

from go_core.scene.artifact import load_scene_artifact, load_scene_cameras, save_scene_artifact
from go_core.scene.loader import load_scene
from go_core.scene.types import Scene, View
from go_core.scene.validate import ValidationReport, validate_scene

__all__ = [
    "Scene",
    "ValidationReport",
    "View",
    "load_scene",
    "load_scene_artifact",
    "load_scene_cameras",
    "save_scene_artifact",
    "validate_scene",
]
