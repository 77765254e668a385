"""A camera's view of a deformed membrane mesh: ray casting, material points, contact.

The world (``sim.mujoco.world``) gives each bubble's outer surface as vertices of the
cap mesh in the finger frame F. :class:`MeshView` casts every pixel's ray (the camera's
own rays, ``geometry.camera``) against the mesh's triangles: each triangle's projection
bounds the pixels it can hold, a pixel inside it hits the triangle's plane at the exact
range along its ray, and the nearest hit wins. Per hit it interpolates (perspective
correct) the vertex normals (for the IR incidence), the vertices' material coordinates
(where on the printed sheet the latex there was, so the dots move with the latex) and
whether the vertices touch the object (the true contact patch).

It returns the arrays the geometric membrane step of ``sim.tof`` adds (``range_m``,
``indentation_m`` against the rest cap, ``contact``, ``cos_incidence``) plus
``material_shift_m``, so the IR, dot pattern and ToF noise effects run unchanged on it.
Pixels whose ray meets no triangle (the rim, where the mesh's chords cut inside the
ellipse) are NaN: no return.
"""

from __future__ import annotations

import numpy as np

from sim.mujoco.mesh import CapMesh, vertex_normals


class MeshView:
    """One camera looking at one membrane mesh (see the module docstring).

    Args:
        mesh: the membrane's mesh (its topology and material coordinates).
        unit_rays: ``(H, W, 3)`` the camera's unit rays in the sensor frame.
        fx_px, fy_px, cx_px, cy_px: its intrinsics.
        finger_from_sensor: the camera's pose in F.
        rest_range_m: ``(H, W)`` range to the rest membrane (NaN off the cap), for the
            indentation.
    """

    def __init__(
        self,
        mesh: CapMesh,
        unit_rays: np.ndarray,
        *,
        fx_px: float,
        fy_px: float,
        cx_px: float,
        cy_px: float,
        finger_from_sensor: np.ndarray,
        rest_range_m: np.ndarray,
    ) -> None:
        self.mesh = mesh
        self.rays = unit_rays.reshape(-1, 3)
        self.shape = unit_rays.shape[:2]
        self.k = (fx_px, fy_px, cx_px, cy_px)
        self.r_fs = finger_from_sensor[:3, :3]
        self.o_f = finger_from_sensor[:3, 3]
        self.rest_range = rest_range_m.astype(np.float32)

    def render(self, surface_f: np.ndarray, touching: np.ndarray) -> dict[str, np.ndarray]:
        """The membrane arrays for a surface (``(N, 3)`` in F) and its vertices' contact."""
        h, w = self.shape
        tri = self.mesh.triangles
        p_s = (np.asarray(surface_f, np.float64) - self.o_f) @ self.r_fs
        n_s = vertex_normals(surface_f, tri) @ self.r_fs
        fx, fy, cx, cy = self.k
        z = p_s[:, 2]
        ok = np.all(z[tri] > 1e-4, axis=1)
        tri = tri[ok]
        zs = np.maximum(z, 1e-4)
        u = fx * p_s[:, 0] / zs + cx
        v = fy * p_s[:, 1] / zs + cy
        tu, tv = u[tri], v[tri]
        c0 = np.clip(np.ceil(tu.min(axis=1)), 0, w).astype(np.int64)
        c1 = np.clip(np.floor(tu.max(axis=1)), -1, w - 1).astype(np.int64)
        r0 = np.clip(np.ceil(tv.min(axis=1)), 0, h).astype(np.int64)
        r1 = np.clip(np.floor(tv.max(axis=1)), -1, h - 1).astype(np.int64)
        bw = np.maximum(c1 - c0 + 1, 0)
        bh = np.maximum(r1 - r0 + 1, 0)
        sizes = bw * bh
        out_range = np.full(h * w, np.nan, np.float32)
        out = {
            "cos": np.ones(h * w, np.float32),
            "material": np.full((h * w, 2), np.nan, np.float32),
            "touch": np.zeros(h * w, np.float32),
        }
        total = int(sizes.sum())
        if total:
            t_id = np.repeat(np.arange(len(tri)), sizes)
            k = np.arange(total) - np.repeat(np.cumsum(sizes) - sizes, sizes)
            col = c0[t_id] + k % bw[t_id]
            row = r0[t_id] + k // bw[t_id]
            # Barycentric coordinates in the image (edge functions of the projection).
            a_u, a_v = tu[t_id, 0], tv[t_id, 0]
            e1u, e1v = tu[t_id, 1] - a_u, tv[t_id, 1] - a_v
            e2u, e2v = tu[t_id, 2] - a_u, tv[t_id, 2] - a_v
            det = e1u * e2v - e2u * e1v
            du, dv = col - a_u, row - a_v
            good = np.abs(det) > 1e-12
            det = np.where(good, det, 1.0)
            l1 = (du * e2v - e2u * dv) / det
            l2 = (e1u * dv - du * e1v) / det
            l0 = 1.0 - l1 - l2
            eps = -1e-9
            inside = good & (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
            t_id, col, row = t_id[inside], col[inside], row[inside]
            lam = np.stack([l0[inside], l1[inside], l2[inside]], axis=1)
            pix = row * w + col
            corners = tri[t_id]
            # The exact hit on the triangle's plane along the pixel's unit ray.
            p0, p1, p2 = (p_s[corners[:, i]] for i in range(3))
            normal = np.cross(p1 - p0, p2 - p0)
            d = self.rays[pix]
            denom = np.einsum("ij,ij->i", normal, d)
            safe = np.abs(denom) > 1e-15
            t = np.einsum("ij,ij->i", normal, p0) / np.where(safe, denom, 1.0)
            hit = safe & (t > 0)
            t, pix, corners, lam, d = t[hit], pix[hit], corners[hit], lam[hit], d[hit]
            # Nearest hit per pixel.
            order = np.lexsort((t, pix))
            first = order[np.unique(pix[order], return_index=True)[1]]
            t, pix, corners, lam, d = t[first], pix[first], corners[first], lam[first], d[first]
            # Perspective-correct weights: screen barycentrics over each vertex's depth.
            persp = lam / z[corners]
            persp /= persp.sum(axis=1, keepdims=True)
            out_range[pix] = t
            nrm = np.einsum("ij,ijk->ik", persp, n_s[corners])
            nrm /= np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
            out["cos"][pix] = np.abs(np.einsum("ij,ij->i", nrm, d))
            out["material"][pix] = np.einsum("ij,ijk->ik", persp, self.mesh.material_yz_m[corners])
            out["touch"][pix] = np.einsum("ij,ij->i", persp, touching[corners].astype(np.float64))
        range_m = out_range.reshape(h, w)
        # Where the latex at each pixel sits on the plate now, against where its material
        # sat: the shift the dot pattern is sampled with (sim.tof's dot step subtracts it).
        rays_f = self.rays.reshape(h, w, 3) @ self.r_fs.T
        now_yz = self.o_f[1:] + range_m[..., None] * rays_f[..., 1:]
        shift = (now_yz - out["material"].reshape(h, w, 2)).astype(np.float32)
        shift[~np.isfinite(shift)] = 0.0
        with np.errstate(invalid="ignore"):
            contact = out["touch"].reshape(h, w) > 0.5
        return {
            "range_m": range_m,
            "indentation_m": (self.rest_range - range_m).astype(np.float32),
            "contact": contact,
            "cos_incidence": out["cos"].reshape(h, w),
            "material_shift_m": shift,
        }
