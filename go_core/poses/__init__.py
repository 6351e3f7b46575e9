"""Camera poses: checking given poses against the images, estimating poses where there are none, and
refining them. Features and matches (``matching``, SIFT or DISK + LightGlue from ``go_core.features``) are
chained into ``tracks``; ``check`` judges given poses by epipolar and leave-one-out reprojection errors,
``sfm`` reconstructs poses with pycolmap and ``estimate`` + ``verify`` refuse an estimate that may be
wrong. ``silhouettes`` (turns a pair's matches ask for, judged by the masks) and ``silhouette_align``
(cameras moved until their silhouettes agree) need no texture, and with ``verify`` share one silhouette
``coverage``; ``refine`` is the per-camera correction optimised during coarse training; ``epipolar`` and
``similarity`` (the similarity between two camera frames, for evaluation) are the geometry they share.
Nothing here imports torch at module level except ``coverage``, ``silhouette_align`` and ``refine``.
"""
