"""The true material flow of a shear, for scoring shear estimates against the simulator.

The simulator prints the dot pattern on the membrane in sheet coordinates and shifts the
sheet by the contact's material shift (``sim.tof``). :func:`truth` follows the material
from a reference frame to a current one: a Newton solve per pixel finds where each
reference dot is now, giving the true image flow, the true shift in the tool's (y, z)
plane and its torsion. :class:`SimGrasp` renders a held object moved in the hand.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

import sim
from geometry.camera import PinholeCamera
from geometry.gripper import GripperGeometry
from geometry.planar import rotation_about_centroid


class SimGrasp:
    """A mug held by the simulated gripper, moved in the hand from its grasp pose.

    The grasp (opening, pose) is the scene's at ``grasp_secs``; :meth:`instant` renders
    both bubbles with the mug shifted along the tool's y and z axes and twisted about
    its x axis (the grasp axis), against the grasp pose as the shear anchor.
    """

    def __init__(self, scene_path: str = "scenes/mug_grasp.yaml", grasp_secs: float = 1.5) -> None:
        self.scene = sim.load_scene(scene_path)
        self.width_m = sim.render(self.scene, grasp_secs).snapshot.width_m
        self.anchor = self.scene.tool_from_object(grasp_secs)
        self.geometry = self.scene.gripper_geometry()
        self.camera = self.scene.camera.intrinsics()

    def pose(self, shift_m: tuple[float, float], twist_rad: float) -> np.ndarray:
        """The anchor twisted about tool x, then shifted along tool (y, z) by ``shift_m``."""
        c, s = math.cos(twist_rad), math.sin(twist_rad)
        rot = np.eye(4)
        rot[1:3, 1:3] = [[c, -s], [s, c]]
        pose = rot @ self.anchor
        pose[1:3, 3] += np.asarray(shift_m)
        return np.asarray(pose)

    def instant(
        self, shift_m: tuple[float, float] = (0.0, 0.0), twist_rad: float = 0.0, index: int = 0
    ) -> sim.Instant:
        """Both bubbles with the mug moved; ``index`` selects the noise draw."""
        return sim.render_grasp(
            self.scene.object.name,
            self.pose(shift_m, twist_rad),
            self.width_m,
            effects=self.scene.effects,
            dims_m=dict(self.scene.object.dims_m),
            anchor_tool_from_object=self.anchor,
            frame_index=index,
            scene=self.scene,
        )


def sheet_coordinates(
    geometry: GripperGeometry, camera: PinholeCamera, arrays: dict[str, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """Per pixel: the printed-sheet coordinates of the material seen there, and the
    finger-frame (y, z) of the membrane point, both ``(h, w, 2)`` metres.

    The simulator textures the membrane point with finger coordinates (y, z) by the
    sheet at ``(y, z) - material_shift`` (``sim.tof``), so equal sheet coordinates in two
    frames mean the same material.
    """
    finger_from_sensor = geometry.finger_from_sensor()
    dirs = camera.unit_rays() @ finger_from_sensor[:3, :3].T
    yz = finger_from_sensor[1:3, 3] + arrays["range_m"][..., None] * dirs[..., 1:]
    return (yz - arrays["material_shift_m"]).astype(np.float32), yz


def truth(
    geometry: GripperGeometry,
    camera: PinholeCamera,
    reference: sim.Instant,
    current: sim.Instant,
    sensor: str,
    mask: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(truth_px, truth_m, torsion_rad)`` of ``current`` against ``reference``, one bubble.

    ``truth_px`` is the mean true image motion of the material over the scored pixels,
    ``truth_m`` its mean shift in the tool's (y, z) plane in metres, ``torsion_rad`` the
    least-squares rotation of that shift field about tool x. ``mask`` selects the
    reference pixels to score (e.g. the estimator's membrane mask); pixels whose
    material cannot be followed are left out.

    The true flow follows the material: for each masked reference pixel ``q`` with sheet
    coordinates ``c``, Newton's method finds the current pixel ``p`` whose material is
    ``c`` (the sheet map is smooth; a few steps converge to 1e-5 m). The material's
    displacement is the change of its membrane point's (y, z), in the tool frame.
    """
    sheet_ref, yz_ref = sheet_coordinates(geometry, camera, reference.frames[sensor].arrays)
    sheet_cur, yz_cur = sheet_coordinates(geometry, camera, current.frames[sensor].arrays)
    mask = mask & np.isfinite(sheet_ref).all(axis=-1)
    h, w = mask.shape
    grid_y, grid_x = np.mgrid[0:h, 0:w].astype(np.float32)
    d_dx = np.gradient(sheet_cur, axis=1)
    d_dy = np.gradient(sheet_cur, axis=0)
    px, py = grid_x.copy(), grid_y.copy()
    residual = np.full((h, w, 2), np.inf, np.float32)

    def sample(image: np.ndarray) -> np.ndarray:
        return cv2.remap(
            image, px, py, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan
        )

    for _ in range(8):
        residual = sample(sheet_cur) - sheet_ref
        jx, jy = sample(d_dx), sample(d_dy)
        det = jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            step_x = -(jy[..., 1] * residual[..., 0] - jy[..., 0] * residual[..., 1]) / det
            step_y = -(-jx[..., 1] * residual[..., 0] + jx[..., 0] * residual[..., 1]) / det
        px = np.where(np.isfinite(step_x), px + np.clip(step_x, -4, 4), px).astype(np.float32)
        py = np.where(np.isfinite(step_y), py + np.clip(step_y, -4, 4), py).astype(np.float32)
    residual = sample(sheet_cur) - sheet_ref
    with np.errstate(invalid="ignore"):
        converged = np.nan_to_num(np.abs(residual).max(axis=-1), nan=np.inf) < 1e-5
    mask &= converged
    flow = np.stack([px - grid_x, py - grid_y], axis=-1)[mask]
    rows, cols = np.nonzero(mask)
    moved_yz = np.stack(
        [
            cv2.remap(yz_cur[..., i].astype(np.float32), px, py, cv2.INTER_LINEAR)[mask]
            for i in (0, 1)
        ],
        axis=1,
    )
    # Finger (y, z) to tool (y, z): the finger's x is the plate normal, so the finger's
    # y-z plane is the tool's; the left finger's y is the tool's -y.
    to_tool = geometry.tool_from_finger(sensor, 0.05)[1:3, 1:3]
    displacement_m = (moved_yz - yz_ref[mask]) @ to_tool.T
    position_m = yz_ref[mask] @ to_tool.T
    torsion, _ = rotation_about_centroid(
        *(np.ascontiguousarray(a[:, i]) for a in (position_m, displacement_m) for i in (0, 1))
    )
    return flow.mean(axis=0), displacement_m.mean(axis=0), torsion
