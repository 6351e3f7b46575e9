"""Render one object of the repair corpus with Blender (bpy) Cycles on the CPU: a NeRF-synthetic scene folder.

Runs under a Python that has the ``bpy`` wheel (``pip install bpy==5.0.1 numpy`` in its own venv: bpy pins
its own numpy), never under the project's interpreter; ``benchmarks/prior/repair_corpus.py`` writes the job
file and calls it::

    ~/.venvs/bpy/bin/python benchmarks/prior/corpus_blender.py JOB.json

JOB.json: ``meshes`` (OBJ paths, joined into one object), ``up`` ("Y" or "Z": the files' up axis), ``out``
(scene folder), ``res``, ``samples``, ``threads``, ``fov_deg``, ``radius``, ``views`` ({"train": [[az, el],
...], "test": [...]} in degrees), ``hdri`` (a Blender studio-light name), ``hdri_strength``,
``hdri_rotation_deg``, ``sun_strength``, ``sun_elevation_deg``, ``sun_azimuth_deg``, ``roughness`` (< 0 keeps
the file's), ``seed`` (Cycles' sampling seed), optional ``metallic`` (0: dielectric), ``max_bounces`` (4),
``adaptive_threshold`` (0.02) and
``mesh_only`` (true: write ``mesh_world.npz`` and nothing else, for folders rendered before it was written).

The scene follows the dev sets' protocol (shared tools' make_scene.py): the object's bounding box centred at
the origin, its bounding sphere scaled to radius 1, +Z up, cameras at ``radius`` looking at the origin with a
``fov_deg`` horizontal field of view, Standard view transform, transparent film (alpha = coverage), 8-bit
RGBA PNGs. Writes ``mesh_world.npz`` (the normalised mesh's triangles in the cameras' world frame, as the dev
scenes carry it: ``vertices`` [V,3] float32, ``faces`` [F,3] int32), ``train/r_i.png``, ``test/r_i.png``,
``transforms_{train,test,val}.json`` and
``render.json`` (Blender version, mesh statistics, seconds per image); ``render.json`` is written last, so
its presence means the folder is complete.
"""

import json
import math
import os
import sys
import time

import bpy
import numpy as np
from mathutils import Matrix

HERE = os.path.dirname(os.path.abspath(__file__))  # benchmarks/prior: the corpus package
sys.path.insert(0, os.path.dirname(os.path.dirname(HERE)))  # the repository: go_core
sys.path.insert(0, HERE)
from corpus.views import camera_to_world  # noqa: E402  (numpy only)

from go_core.io.npz import write_npz_deterministic  # noqa: E402  (numpy only)


def import_meshes(paths, up):
    """Import every OBJ, bake transforms and join them into one mesh object."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for path in paths:
        if up == "Y":
            bpy.ops.wm.obj_import(filepath=path, forward_axis="NEGATIVE_Z", up_axis="Y")
        else:
            bpy.ops.wm.obj_import(filepath=path, forward_axis="Y", up_axis="Z")
    objs = [o for o in bpy.data.objects if o.type == "MESH"]
    if not objs:
        raise SystemExit(f"no mesh imported from {paths}")
    bpy.ops.object.select_all(action="DESELECT")
    for o in objs:
        o.select_set(True)
    bpy.context.view_layer.objects.active = objs[0]
    bpy.ops.object.parent_clear(type="CLEAR_KEEP_TRANSFORM")
    if len(objs) > 1:
        bpy.ops.object.join()
    obj = bpy.context.view_layer.objects.active
    bpy.ops.object.transform_apply(location=True, rotation=True, scale=True)
    return obj


def normalise(obj):
    """Bounding-box centre to the origin, bounding-sphere radius 1 (baked into the vertices)."""
    n = len(obj.data.vertices)
    co = np.empty(n * 3, dtype=np.float64)
    obj.data.vertices.foreach_get("co", co)
    co = co.reshape(-1, 3)
    centre = 0.5 * (co.min(0) + co.max(0))
    scale = 1.0 / np.linalg.norm(co - centre, axis=1).max()
    obj.data.vertices.foreach_set("co", ((co - centre) * scale).astype(np.float32).ravel())
    obj.data.update()
    return {"vertices": n, "faces": len(obj.data.polygons), "scale": float(scale), "centre": centre.tolist()}


def write_mesh_world(obj, out):
    """The normalised mesh as triangles (n-gons split as Blender renders them) in ``out/mesh_world.npz``."""
    data = obj.data
    data.calc_loop_triangles()
    n = len(data.vertices)
    co = np.empty(n * 3, dtype=np.float32)
    data.vertices.foreach_get("co", co)
    tris = np.empty(len(data.loop_triangles) * 3, dtype=np.int32)
    data.loop_triangles.foreach_get("vertices", tris)
    os.makedirs(out, exist_ok=True)
    write_npz_deterministic(
        os.path.join(out, "mesh_world.npz"), {"vertices": co.reshape(-1, 3), "faces": tris.reshape(-1, 3)}
    )


def fix_materials(obj, roughness, metallic=0.0):
    """Dielectric materials (or ``metallic`` > 0 for a metal), optional roughness override, cubic texture
    filtering."""
    for slot in obj.material_slots:
        mat = slot.material
        if mat is None or not mat.use_nodes:
            continue
        for node in mat.node_tree.nodes:
            if node.type == "BSDF_PRINCIPLED":
                node.inputs["Metallic"].default_value = float(metallic)
                if roughness >= 0:
                    node.inputs["Roughness"].default_value = roughness
            if node.type == "TEX_IMAGE" and node.image is not None:
                node.interpolation = "Cubic"


def setup_lighting(job):
    """A bundled studio-light HDRI (rotated, scaled) as the world, plus an optional soft sun."""
    world = bpy.data.worlds.new("World")
    bpy.context.scene.world = world
    world.use_nodes = True
    nt = world.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputWorld")
    bg = nt.nodes.new("ShaderNodeBackground")
    bg.inputs["Strength"].default_value = float(job["hdri_strength"])
    path = os.path.join(bpy.utils.system_resource("DATAFILES"), "studiolights", "world", job["hdri"] + ".exr")
    env = nt.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(path)
    mapping = nt.nodes.new("ShaderNodeMapping")
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, math.radians(float(job["hdri_rotation_deg"])))
    tc = nt.nodes.new("ShaderNodeTexCoord")
    nt.links.new(tc.outputs["Generated"], mapping.inputs["Vector"])
    nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    nt.links.new(bg.outputs["Background"], out.inputs["Surface"])
    if float(job["sun_strength"]) > 0:
        sun = bpy.data.lights.new("key", type="SUN")
        sun.energy = float(job["sun_strength"])
        sun.angle = math.radians(12.0)
        o = bpy.data.objects.new("key", sun)
        bpy.context.scene.collection.objects.link(o)
        o.rotation_euler = (
            math.radians(90.0 - job["sun_elevation_deg"]),
            0.0,
            math.radians(job["sun_azimuth_deg"]),
        )


def setup_render(job):
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = int(job["samples"])
    sc.cycles.seed = int(job["seed"])
    sc.cycles.use_adaptive_sampling = True
    sc.cycles.adaptive_threshold = float(job.get("adaptive_threshold", 0.02))
    sc.cycles.use_denoising = True
    sc.cycles.denoiser = "OPENIMAGEDENOISE"
    sc.cycles.max_bounces = int(job.get("max_bounces", 4))
    sc.render.threads_mode = "FIXED"
    sc.render.threads = int(job["threads"])
    sc.render.resolution_x = sc.render.resolution_y = int(job["res"])
    sc.render.resolution_percentage = 100
    sc.render.film_transparent = True
    sc.render.use_persistent_data = True
    settings = sc.render.image_settings
    settings.file_format, settings.color_mode, settings.color_depth = "PNG", "RGBA", "8"
    for attr in dir(sc.render):  # no date / render-stat text chunks in the PNGs
        if attr.startswith("use_stamp"):
            try:
                setattr(sc.render, attr, False)
            except (AttributeError, TypeError):
                pass
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"


def make_camera(fov_deg):
    cam = bpy.data.cameras.new("cam")
    cam.sensor_fit, cam.sensor_width = "HORIZONTAL", 36.0
    cam.lens_unit, cam.angle = "FOV", math.radians(fov_deg)
    cam.clip_start, cam.clip_end = 0.05, 100.0
    o = bpy.data.objects.new("cam", cam)
    bpy.context.scene.collection.objects.link(o)
    bpy.context.scene.camera = o
    return o


def render_split(job, cam, split):
    out = job["out"]
    os.makedirs(os.path.join(out, split), exist_ok=True)
    frames, seconds = [], []
    for i, (az, el) in enumerate(job["views"][split]):
        c2w = camera_to_world(az, el, job["radius"])
        cam.matrix_world = Matrix(c2w.tolist())
        bpy.context.view_layer.update()
        bpy.context.scene.render.filepath = os.path.join(out, split, f"r_{i}.png")
        t0 = time.process_time()
        bpy.ops.render.render(write_still=True)
        seconds.append(time.process_time() - t0)
        frames.append(
            {
                "file_path": f"./{split}/r_{i}",
                "azimuth_deg": az,
                "elevation_deg": el,
                "transform_matrix": c2w.tolist(),
            }
        )
    w = int(job["res"])
    angle_x = cam.data.angle_x
    fl = 0.5 * w / math.tan(0.5 * angle_x)
    meta = {
        "camera_angle_x": angle_x,
        "fl_x": fl,
        "fl_y": fl,
        "cx": w / 2,
        "cy": w / 2,
        "w": w,
        "h": w,
        "frames": frames,
    }
    names = [split] + (["val"] if split == "test" else [])
    for name in names:
        with open(os.path.join(out, f"transforms_{name}.json"), "w") as fh:
            json.dump(meta, fh, indent=1)
    return seconds


def main():
    with open(sys.argv[-1]) as fh:
        job = json.load(fh)
    t0 = time.process_time()
    obj = import_meshes(job["meshes"], job["up"])
    mesh = normalise(obj)
    write_mesh_world(obj, job["out"])
    if job.get("mesh_only"):
        return
    fix_materials(obj, float(job["roughness"]), float(job.get("metallic", 0.0)))
    setup_lighting(job)
    setup_render(job)
    cam = make_camera(float(job["fov_deg"]))
    seconds = render_split(job, cam, "train") + render_split(job, cam, "test")
    info = {
        "renderer": f"Blender {bpy.app.version_string} Cycles CPU",
        "mesh": mesh,
        "cpu_s_per_image": round(float(np.mean(seconds)), 3),
        "cpu_s": round(time.process_time() - t0, 2),
    }
    with open(os.path.join(job["out"], "render.json"), "w") as fh:
        json.dump(info, fh, indent=1)


if __name__ == "__main__":
    main()
