"""A texture atlas for the exported mesh: charts from xatlas, colours baked from the model's own renders.

The vertex colours of the fused mesh are the TSDF's colour volume interpolated at the vertices: one colour
per voxel-sized patch, averaged over every view that saw it. A texture holds the renders' detail at a finer
pitch than the vertices. ``textured_mesh`` decimates the mesh to a face budget (xatlas's charting grows
faster than linearly with the face count: 10 000 faces ~2 s, 20 000 ~10 s on one loaded core), unwraps it,
and gives every texel the colour the bake views see at its 3-D point: the mean over the views whose median
depth there is the texel's own (the fusion's surface test, go_core.mesh.tsdf.SurfaceLookup.on_surface),
weighted by the cosine between the face normal and the view ray to the power ``sharpness``. Texels that no
view sees keep the colour volume's colour; empty texels next to charts take their neighbours' colours, so
a viewer's bilinear filtering at chart borders does not blend in the background. Deterministic.

UV convention (trimesh's, which its glTF export converts): u to the right, v up, so texel row ``r`` of an
``H``-row image is at v = 1 − (r + ½) / H.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from go_core.mesh.types import TexturedMesh, TriMesh

if TYPE_CHECKING:
    from go_core.mesh.tsdf import FusionRule, View


def unwrap(mesh: TriMesh, resolution: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """xatlas charts of ``mesh`` packed into about ``resolution``² texels: (index of each new vertex's
    original vertex [V'], faces [F,3] on the new vertices, uvs [V',2] in [0,1], (width, height))."""
    import xatlas

    atlas = xatlas.Atlas()
    atlas.add_mesh(mesh.vertices.astype(np.float32), mesh.faces.astype(np.uint32))
    charts = xatlas.ChartOptions()
    charts.max_iterations = 1
    pack = xatlas.PackOptions()
    pack.resolution = int(resolution)
    pack.padding = 2
    pack.bruteForce = False
    atlas.generate(charts, pack)
    vmap, faces, uvs = atlas[0]
    return (
        np.asarray(vmap, np.int64),
        np.asarray(faces, np.int64),
        np.asarray(uvs, np.float64),
        (int(atlas.width), int(atlas.height)),
    )


def texel_samples(
    faces: np.ndarray, uvs: np.ndarray, size: tuple[int, int], chunk: int = 1 << 14
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The texels whose centres lie in a face's uv triangle: flat texel index [N] (row-major, row 0 at
    v = 1), face [N] and barycentric coordinates [N,3]; a texel in two faces' triangles (charts touch only
    at padding) keeps the first."""
    w, h = size
    tri = uvs[faces] * np.array([w, h])  # [F,3,2] in texel units, y up
    tri[..., 1] = h - tri[..., 1]  # y down: row coordinate
    lo = np.floor(tri.min(axis=1) - 0.5).astype(np.int64).clip(0, [w - 1, h - 1])
    hi = np.ceil(tri.max(axis=1) - 0.5).astype(np.int64).clip(0, [w - 1, h - 1])
    out_idx, out_face, out_bary = [], [], []
    for start in range(0, len(faces), chunk):
        sl = slice(start, start + chunk)
        ext = hi[sl] - lo[sl] + 1  # [C,2] bbox sizes
        counts = ext[:, 0] * ext[:, 1]
        face = np.repeat(np.arange(start, start + len(counts)), counts)
        local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
        ex = np.repeat(ext[:, 0], counts)
        x = np.repeat(lo[sl][:, 0], counts) + local % ex
        y = np.repeat(lo[sl][:, 1], counts) + local // ex
        p = np.stack([x + 0.5, y + 0.5], axis=1)
        a, b, c = tri[face, 0], tri[face, 1], tri[face, 2]
        v0, v1, v2 = b - a, c - a, p - a
        den = v0[:, 0] * v1[:, 1] - v1[:, 0] * v0[:, 1]
        ok = np.abs(den) > 1e-12
        den = np.where(ok, den, 1.0)
        beta = (v2[:, 0] * v1[:, 1] - v1[:, 0] * v2[:, 1]) / den
        gamma = (v0[:, 0] * v2[:, 1] - v2[:, 0] * v0[:, 1]) / den
        bary = np.stack([1.0 - beta - gamma, beta, gamma], axis=1)
        inside = ok & (bary >= -1e-9).all(axis=1)
        out_idx.append(y[inside] * w + x[inside])
        out_face.append(face[inside])
        out_bary.append(bary[inside])
    idx, face, bary = np.concatenate(out_idx), np.concatenate(out_face), np.concatenate(out_bary)
    idx, first = np.unique(idx, return_index=True)
    return idx, face[first], bary[first]


def bake_colours(
    points: np.ndarray,
    normals: np.ndarray,
    views: list[View],
    rule: FusionRule,
    sharpness: float,
    chunk: int = 1 << 17,
) -> tuple[np.ndarray, np.ndarray]:
    """Colours [N,3] at surface ``points`` [N,3] with outward unit ``normals``: the cosine^``sharpness``
    weighted mean of the views' colours at the points they see as surface; and the weight sums [N]
    (0: no view saw the point, its colour is 0)."""
    import torch

    from go_core.mesh.tsdf import PackedView

    if any(v.rgb is None for v in views):
        raise ValueError("baking needs views rendered with colour")
    packed = [PackedView(v, rule) for v in views]
    centres = [torch.as_tensor(v.camera.center, dtype=torch.float32) for v in views]
    pts = torch.as_tensor(np.asarray(points, np.float32))
    nrm = torch.as_tensor(np.asarray(normals, np.float32))
    rgb = torch.zeros(len(pts), 3)
    weight = torch.zeros(len(pts))
    for start in range(0, len(pts), chunk):
        p, n = pts[start : start + chunk], nrm[start : start + chunk]
        for view, centre in zip(packed, centres, strict=True):
            ray = centre - p
            cos = (ray * n).sum(1) / ray.norm(dim=1).clamp_min(1e-12)
            hit = view.lookup(p, rule)
            w = cos.clamp_min(0.0).pow(sharpness) * hit.on_surface()
            rgb[start : start + chunk] += w[:, None] * view.rgb[hit.pix]
            weight[start : start + chunk] += w
    out = rgb / weight.clamp_min(1e-12)[:, None]
    return out.numpy(), weight.numpy()


def dilate_texture(texture: np.ndarray, filled: np.ndarray, iterations: int) -> np.ndarray:
    """``texture`` [H,W,3] float with its unfilled texels next to filled ones set to the mean of their
    filled 8-neighbours, ``iterations`` times (a gutter against bilinear bleeding at chart borders)."""
    tex, mask = texture.copy(), filled.astype(np.float32)
    for _ in range(iterations):
        pad_t = np.pad(tex * mask[..., None], ((1, 1), (1, 1), (0, 0)))
        pad_m = np.pad(mask, 1)
        h, w = mask.shape
        total = sum(pad_t[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1))
        count = sum(pad_m[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1))
        grow = (mask == 0) & (count > 0)
        tex[grow] = total[grow] / count[grow, None]
        mask = np.where(grow, 1.0, mask)
    return tex


def textured_mesh(
    mesh: TriMesh,
    views: list[View],
    rule: FusionRule,
    fallback,
    resolution: int,
    sharpness: float,
    gutter: int = 4,
) -> TexturedMesh:
    """``mesh`` unwrapped by xatlas (charts packed for about ``resolution``² texels) and baked from
    ``views`` (rendered with colour; ``bake_colours`` with ``sharpness``) into a ``resolution`` x
    ``resolution`` texture (a power of two by default, for old WebGL's mipmaps; measured no worse than
    xatlas's own slightly larger size). ``fallback(points [N,3]) -> colours [N,3]`` colours the texels no
    view sees (the colour volume's colour, as the vertices get)."""
    vmap, faces, uvs, _ = unwrap(mesh, resolution)
    size = (int(resolution), int(resolution))  # xatlas packs to about this; uvs are normalised, so bake at it
    vertices = mesh.vertices[vmap]
    idx, face, bary = texel_samples(faces, uvs, size)
    corners = vertices[faces[face]]  # [N,3,3]
    points = np.einsum("nk,nkd->nd", bary, corners)
    normals = TriMesh(vertices, faces).face_normals()[face]
    colours, weight = bake_colours(points, normals, views, rule, sharpness)
    unseen = weight <= 0
    if unseen.any():
        colours[unseen] = fallback(points[unseen])
    w, h = size
    texture = np.zeros((h * w, 3), np.float32)
    filled = np.zeros(h * w, bool)
    texture[idx], filled[idx] = colours, True
    texture = dilate_texture(texture.reshape(h, w, 3), filled.reshape(h, w), gutter)
    image = np.round(np.clip(texture, 0.0, 1.0) * 255).astype(np.uint8)
    return TexturedMesh(vertices, faces, uvs, image)


__all__ = ["bake_colours", "dilate_texture", "textured_mesh", "texel_samples", "unwrap"]
