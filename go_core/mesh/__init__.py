"""Meshes from Gaussians and masks (docs/geometry.md).

* ``views``: the cameras depth is rendered from (the training ellipse plus a sphere of views);
* ``tsdf``: truncated-signed-distance fusion of depth + alpha maps on a voxel grid (vectorised torch);
* ``surface``: marching cubes, largest component, decimation, vertex colours (the ``TriMesh`` type);
* ``hull_mesh``: the visual hull's own surface (carved from the training masks), the geometry baseline;
* ``extract``: the whole chain for a Gaussian model (its settings: ``settings``, torch-free);
* ``files``: ``model_mesh.ply`` / ``model.glb`` writers and the ground-truth ``mesh_world.npz`` reader.
"""
