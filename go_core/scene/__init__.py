"""Scene input: read a scene folder (NeRF-synthetic or COLMAP) into a ``Scene``, validate it, and save /
load the ``scene`` step's artifact that every downstream step reads; ``masking`` gives the training views'
object masks (provided ones validated, else GrabCut or a local ONNX model); ``auto_mask`` the auto masks
(u2netp from ``salient_weights``, post-processing from ``mask_post``, the user's box from ``object_hint``).

* ``loader.load_scene(path, views=0, max_size=0) -> Scene`` (raises ``SceneError`` at the first problem)
* ``validate.validate_scene(path, views=0) -> ValidationReport`` (collects every problem; ``.ok``,
  ``.summary()``)
* ``artifact.save_scene_artifact(scene, out_dir)`` / ``artifact.load_scene_artifact(dir) -> Scene``
* ``types.Scene``, ``types.View``

This package's ``__init__`` imports nothing: import from the module. A step that only reads the scene
artifact (every step after ``scene``) then does not import, and so does not carry in its cache key
(go_pipeline.codehash), the readers, the validation, the photo route's SfM and the feature matcher.
"""
