r"""Body collision model from a URDF's collision meshes: spheres that cover every mesh vertex.

For every link with collision geometry (the fixed base excepted: it cannot move away from an
obstacle), the vertices V of its collision meshes, in the link frame (each ``<collision>``'s
``<origin>`` and mesh ``scale`` applied; boxes, cylinders and spheres contribute surface points),
are cut into k slabs of equal width along their principal axis; each slab gets the smallest
enclosing sphere of its vertices and of points sampled on the hull surface (Bădoiu–Clarkson
iterations for the centre, then the radius is the largest point distance from it, minus
``tolerance``). So every vertex lies inside the link's
union of spheres or at most ``tolerance`` [m] outside it. k = 1..``max_spheres`` is chosen to
minimise ``(V(U \\ H) + 4 V(H \\ U)) · (1 + k_penalty (k − 1))`` (volumes below; fewer spheres
are cheaper for the fabric).

Volumes, per link, by seeded Monte Carlo: the mesh is taken as its convex hull H (PyBullet
collides a moving link's mesh as its convex hull), U is the union of the link's spheres. Stated:
V(H), V(U), the excess V(U \ H) (space the spheres claim around the arm: an obstacle there is
avoided although it would not touch) and the miss V(H \ U) (hull volume outside every sphere:
covering the vertices does not cover the hull between two spheres; should be ~0).

numpy and scipy only (meshes: binary/ASCII STL and OBJ, parsed here).
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass

import numpy as np

from tamedpuma.errors import ConfigError
from tamedpuma.robot.rotations import rpy_to_matrix

# ---------------------------------------------------------------- meshes and the URDF


def load_mesh(path: str) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (T, 3) of an STL (binary or ASCII) or OBJ file."""
    ext = os.path.splitext(path)[1].lower()
    try:
        raw = open(path, "rb").read()
    except OSError as exc:
        raise ConfigError(f"cannot read mesh {path}: {exc.strerror}") from None
    if ext == ".obj":
        verts, faces = [], []
        for line in raw.decode("utf-8", "replace").splitlines():
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                faces += [[idx[0], idx[j], idx[j + 1]] for j in range(1, len(idx) - 1)]
        return np.array(verts, float).reshape(-1, 3), np.array(faces, int).reshape(-1, 3)
    if ext == ".stl":
        if raw[:5] == b"solid" and b"facet" in raw[:1000]:
            pts = [[float(x) for x in line.split()[1:4]]
                   for line in raw.decode("utf-8", "replace").splitlines()
                   if line.strip().startswith("vertex")]
            tri = np.array(pts, float).reshape(-1, 3, 3)
        else:
            n = int(np.frombuffer(raw[80:84], np.uint32)[0])
            rec = np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
            tri = np.frombuffer(raw[84:84 + 50 * n], rec)["v"].astype(float)
        verts, inverse = np.unique(tri.reshape(-1, 3), axis=0, return_inverse=True)
        return verts, inverse.reshape(-1, 3)
    raise ConfigError(f"unsupported mesh format {ext!r} ({path}); STL or OBJ")


@dataclass(frozen=True)
class LinkGeometry:
    """Collision geometry of one link, link frame [m]: vertices (V, 3) and closed-surface
    triangles (T, 3) indexing them (primitives are given as sampled surface points, no faces)."""

    link: str
    vertices: np.ndarray
    triangles: np.ndarray
    volume: float  # [m³] of the vertices' convex hull


def _hull_volume(points: np.ndarray) -> float:
    from scipy.spatial import ConvexHull

    try:
        return float(ConvexHull(points).volume)
    except Exception:  # degenerate (flat) point sets
        return 0.0


def _primitive_points(geom: ET.Element) -> np.ndarray | None:
    box, cyl, sph = geom.find("box"), geom.find("cylinder"), geom.find("sphere")
    if box is not None:
        h = np.array([float(x) for x in box.get("size").split()]) / 2
        return np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h
    ang = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    if cyl is not None:
        r, length = float(cyl.get("radius")), float(cyl.get("length"))
        ring = np.stack([r * np.cos(ang), r * np.sin(ang)], axis=1)
        return np.concatenate([np.column_stack([ring, np.full(32, z)])
                               for z in (-length / 2, length / 2)])
    if sph is not None:
        r = float(sph.get("radius"))
        u = np.random.default_rng(0).normal(size=(200, 3))
        return r * u / np.linalg.norm(u, axis=1, keepdims=True)
    return None


def urdf_collision_geometry(urdf_path: str) -> dict[str, LinkGeometry]:
    """Every link's collision geometry (link frame) of a URDF; mesh paths relative to the URDF's
    folder (``package://`` stripped)."""
    try:
        root = ET.parse(urdf_path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ConfigError(f"cannot read URDF {urdf_path}: {exc}") from None
    base = os.path.dirname(os.path.abspath(urdf_path))
    out = {}
    for link in root.findall("link"):
        verts, tris = [], []
        for col in link.findall("collision"):
            origin = col.find("origin")
            xyz = np.zeros(3) if origin is None else np.array(
                [float(x) for x in origin.get("xyz", "0 0 0").split()])
            rot = np.eye(3) if origin is None else rpy_to_matrix(
                [float(x) for x in origin.get("rpy", "0 0 0").split()])
            geom = col.find("geometry")
            mesh = geom.find("mesh") if geom is not None else None
            if mesh is not None:
                name = mesh.get("filename").replace("package://", "")
                path = name if os.path.isabs(name) else os.path.join(base, name)
                v, t = load_mesh(path)
                scale = np.array([float(x) for x in mesh.get("scale", "1 1 1").split()])
                v = v * scale
            elif geom is not None and (v := _primitive_points(geom)) is not None:
                t = np.zeros((0, 3), int)
            else:
                continue
            tris.append(t + sum(len(x) for x in verts))
            verts.append(v @ rot.T + xyz)
        if verts:
            v = np.concatenate(verts)
            out[link.get("name")] = LinkGeometry(link.get("name"), v, np.concatenate(tris),
                                                 _hull_volume(v))
    return out


# ---------------------------------------------------------------- spheres


def enclosing_sphere(points: np.ndarray, iterations: int = 2000) -> tuple[np.ndarray, float]:
    """Centre and radius of a sphere holding every point: Bădoiu–Clarkson (move the centre
    1/(i+1) of the way to the farthest point), radius = the largest distance from the centre."""
    from scipy.spatial import ConvexHull

    try:  # the farthest point is always a hull vertex
        points = points[ConvexHull(points).vertices]
    except Exception:  # flat or tiny sets: keep them all
        pass
    c = points.mean(0)
    for i in range(1, iterations + 1):
        far = points[np.argmax(np.einsum("ij,ij->i", points - c, points - c))]
        c = c + (far - c) / (i + 1)
    return c, float(np.linalg.norm(points - c, axis=1).max())


def volumes(vertices: np.ndarray, centers: np.ndarray, radii: np.ndarray,
            samples: int = 100_000, seed: int = 0) -> dict:
    """V(H), V(U), V(U \\ H), V(H \\ U) [m³] of the vertices' hull H and the spheres' union U."""
    from scipy.spatial import ConvexHull

    centers, radii = np.asarray(centers, float).reshape(-1, 3), np.asarray(radii, float)
    lo = np.minimum(vertices.min(0), (centers - radii[:, None]).min(0))
    hi = np.maximum(vertices.max(0), (centers + radii[:, None]).max(0))
    pts = np.random.default_rng(seed).uniform(lo, hi, size=(samples, 3))
    in_u = outside_distance(pts, centers, radii) <= 0
    try:
        eq = ConvexHull(vertices).equations  # a·x + b ≤ 0 inside, per facet
        in_h = (pts @ eq[:, :3].T + eq[:, 3] <= 1e-12).all(axis=1)
    except Exception:  # flat geometry: no interior
        in_h = np.zeros(len(pts), bool)
    box = float(np.prod(hi - lo))
    return {"hull": in_h.mean() * box, "union": in_u.mean() * box,
            "excess": (in_u & ~in_h).mean() * box, "missed": (in_h & ~in_u).mean() * box}


def outside_distance(points: np.ndarray, centers: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Per point, how far [m] it lies outside the union of spheres (≤ 0: inside)."""
    d = np.linalg.norm(points[:, None] - np.asarray(centers)[None], axis=-1) - np.asarray(radii)
    return d.min(axis=1)


def hull_surface_points(vertices: np.ndarray, n: int = 3000, seed: int = 0) -> np.ndarray:
    """n points uniform on the convex hull's surface (area-weighted triangles), seeded."""
    from scipy.spatial import ConvexHull

    try:
        tri = vertices[ConvexHull(vertices).simplices]
    except Exception:
        return np.zeros((0, 3))
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(tri), size=n, p=area / area.sum())
    u, w = rng.uniform(size=(2, n))
    flip = u + w > 1
    u[flip], w[flip] = 1 - u[flip], 1 - w[flip]
    t = tri[pick]
    return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + w[:, None] * (t[:, 2] - t[:, 0])


def fit_link(geom: LinkGeometry, k: int, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """k spheres (centres (k, 3), radii (k,)) over k principal-axis slabs of the vertices and of
    points sampled on their convex hull's surface (so the hull between slabs is covered too)."""
    v = np.concatenate([geom.vertices, hull_surface_points(geom.vertices)])
    mean = v.mean(0)
    axis = np.linalg.svd(v - mean, full_matrices=False)[2][0]
    t = (v - mean) @ axis
    edges = np.linspace(t.min(), t.max(), k + 1)
    centers, radii = [], []
    for i in range(k):
        sel = v[(t >= edges[i]) & (t <= edges[i + 1] + 1e-12)]
        if len(sel) == 0:
            continue
        c, r = enclosing_sphere(sel)
        centers.append(c)
        radii.append(max(r - tolerance, 1e-4))
    return np.array(centers), np.array(radii)


@dataclass(frozen=True)
class LinkSpheres:
    """The fitted spheres of one link and how well they fit (see the module docstring)."""

    link: str
    centers: np.ndarray       # (k, 3) link frame [m]
    radii: np.ndarray         # (k,) [m]
    max_outside: float        # largest vertex distance outside the spheres [m] (≤ tolerance)
    hull_volume: float        # V(H) [m³]
    union_volume: float       # V(U) [m³]
    excess_volume: float      # V(U \ H) [m³]
    missed_volume: float      # V(H \ U) [m³]


def fit_body(urdf_path: str, links: list[str] | None = None, *, tolerance: float = 0.0,
             max_spheres: int = 3, k_penalty: float = 0.15, skip: tuple[str, ...] = (),
             merge: dict | None = None, samples: int = 100_000) -> list[LinkSpheres]:
    """Spheres for every link with collision geometry (or ``links``), except ``skip``.

    merge: ``{link: (target_link, R, p)}``: the link's vertices are moved into the target's frame
    (x_target = R x + p) and covered with the target's spheres (e.g. locked gripper fingers).
    """
    geoms = dict(urdf_collision_geometry(urdf_path))
    for name, (target, rot, pos) in (merge or {}).items():
        if name not in geoms or target not in geoms:
            raise ConfigError(f"body model merge: {name!r} or {target!r} has no collision mesh")
        v = np.concatenate([geoms[target].vertices,
                            geoms.pop(name).vertices @ np.asarray(rot).T + np.asarray(pos)])
        geoms[target] = LinkGeometry(target, v, np.zeros((0, 3), int), _hull_volume(v))
    names = links if links is not None else [n for n in geoms if n not in skip]
    out = []
    for name in names:
        if name not in geoms:
            raise ConfigError(f"link {name!r} has no collision geometry in {urdf_path}")
        g = geoms[name]
        best = None
        for k in range(1, max_spheres + 1):
            c, r = fit_link(g, k, tolerance)
            vol = volumes(g.vertices, c, r, samples=max(samples // 5, 1000))
            score = (vol["excess"] + 4 * vol["missed"]) * (1 + k_penalty * (k - 1))
            if best is None or score < best[0]:
                best = (score, c, r, vol)
        _, c, r, _ = best
        vol = volumes(g.vertices, c, r, samples=samples)
        out.append(LinkSpheres(name, c, r, float(outside_distance(g.vertices, c, r).max()),
                               vol["hull"], vol["union"], vol["excess"], vol["missed"]))
    return out


def coverage_of(urdf_path: str, spheres, link_frames, links: list[str]) -> dict:
    """How a sphere set ``[(link, offset (3,), radius)]`` (offsets in link frames [m]) covers the
    collision-mesh vertices of ``links``, all placed in the world by ``link_frames(link) -> (R, p)``
    (any one configuration): fraction of vertices inside, worst distance outside [m]."""
    geoms = urdf_collision_geometry(urdf_path)
    world_pts, centers, radii = [], [], []
    for name in links:
        rot, pos = link_frames(name)
        world_pts.append(geoms[name].vertices @ rot.T + pos)
    for link, offset, radius in spheres:
        rot, pos = link_frames(link)
        centers.append(rot @ np.asarray(offset, float) + pos)
        radii.append(radius)
    pts = np.concatenate(world_pts)
    d = outside_distance(pts, np.array(centers), np.array(radii))
    return {"vertices": int(len(pts)), "inside_fraction": float((d <= 1e-9).mean()),
            "max_outside_m": float(max(d.max(), 0.0))}
