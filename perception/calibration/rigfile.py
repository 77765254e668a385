"""A rig's calibration file: what was measured on which devices, each value with its uncertainty.

Written by ``launch.py calibrate`` (:mod:`perception.calibration.procedure`), read by the
hardware graph's device nodes (``bubble_camera.royale`` and ``pressure.usb``, parameter
``calibration``). YAML, read with ``safe_load``::

    rig: lab-gripper-1
    date: '2026-11-26T10:00:00+00:00'
    cameras:
      left:
        camera_id: 0005-1203-0034-2215       # the serial the mount belongs to
        finger_from_sensor: [[...], [...], [...], [0, 0, 0, 1]]
        rotation_sigma_deg: 0.05             # 1-sigma, each axis
        translation_sigma_mm: 0.04
        intrinsics: {fx: 210.5, fy: 210.9, cx: 111.4, cy: 86.2, k1: ..., ...}
        reference: {noise_m: 0.0009, invalid_fraction: 0.31, frames: 30}
    pressure:
      left: {serial: BUBBLE-L, offset_pa: 23.7, offset_sigma_pa: 0.1, noise_pa: 0.4}

A device node given a file checks that it was made for its device (the camera id, the
bridge's serial) and refuses it otherwise, saying which serial the file names and which
is plugged in: a mount measured on one camera says nothing about another.
"""

from __future__ import annotations

import datetime
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from geometry.gripper import SIDES
from geometry.mount import CameraMounts, check_pose


class CalibrationError(ValueError):
    """A calibration file that cannot be read or does not belong to this device."""


@dataclass(frozen=True)
class CameraCalibration:
    """One camera: its serial, its mount in its finger and what the free bubble looked like."""

    camera_id: str
    finger_from_sensor: np.ndarray
    rotation_sigma_deg: float
    translation_sigma_mm: float
    intrinsics: Mapping[str, float] = field(default_factory=dict)
    reference: Mapping[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class PressureCalibration:
    """One pressure sensor: its bridge's serial and its zero (the reading at ambient)."""

    serial: str
    offset_pa: float
    offset_sigma_pa: float
    noise_pa: float = 0.0


@dataclass(frozen=True)
class RigCalibration:
    """A whole rig's calibration (see the module docstring)."""

    rig: str
    date: str
    cameras: Mapping[str, CameraCalibration] = field(default_factory=dict)
    pressure: Mapping[str, PressureCalibration] = field(default_factory=dict)
    source: str = ""

    def mounts(self) -> CameraMounts:
        return CameraMounts({s: c.finger_from_sensor for s, c in self.cameras.items()})

    def camera(self, side: str, camera_id: str) -> CameraCalibration:
        """``side``'s camera calibration, checked against the camera plugged in."""
        cal = self.cameras.get(side)
        self._check("cameras", side, "camera", None if cal is None else cal.camera_id, camera_id)
        assert cal is not None
        return cal

    def pressure_sensor(self, side: str, serial: str) -> PressureCalibration:
        """``side``'s pressure calibration, checked against the bridge plugged in."""
        cal = self.pressure.get(side)
        self._check(
            "pressure", side, "pressure bridge", None if cal is None else cal.serial, serial
        )
        assert cal is not None
        return cal

    def _check(self, section: str, side: str, what: str, made_for: str | None, here: str) -> None:
        if made_for is None:
            raise CalibrationError(f"{self.source}: no `{section}.{side}` in this calibration")
        if made_for != here:
            raise CalibrationError(
                f"{self.source}: made for {side} {what} {made_for!r} (rig {self.rig!r},"
                f" {self.date}), but {what} {here!r} is plugged in: what was measured on"
                " one device says nothing about another; calibrate this rig (launch.py"
                " calibrate) or give its own file"
            )

    def to_dict(self) -> dict[str, Any]:
        return {
            "rig": self.rig,
            "date": self.date,
            "cameras": {
                s: {
                    "camera_id": c.camera_id,
                    "finger_from_sensor": np.round(c.finger_from_sensor, 9).tolist(),
                    "rotation_sigma_deg": round(float(c.rotation_sigma_deg), 5),
                    "translation_sigma_mm": round(float(c.translation_sigma_mm), 5),
                    "intrinsics": {k: float(v) for k, v in c.intrinsics.items()},
                    "reference": {k: float(v) for k, v in c.reference.items()},
                }
                for s, c in self.cameras.items()
            },
            "pressure": {
                s: {
                    "serial": p.serial,
                    "offset_pa": round(float(p.offset_pa), 4),
                    "offset_sigma_pa": round(float(p.offset_sigma_pa), 4),
                    "noise_pa": round(float(p.noise_pa), 4),
                }
                for s, p in self.pressure.items()
            },
        }

    def save(self, path: str | Path) -> None:
        text = yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None)
        Path(path).write_text(
            "# A rig calibration written by `launch.py calibrate` (docs/devices.md).\n" + text
        )


def now_text() -> str:
    return datetime.datetime.now(datetime.UTC).replace(microsecond=0).isoformat()


def _number(where: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise CalibrationError(f"{where}: must be a finite number, got {value!r}")
    return float(value)


def _text(where: str, value: Any) -> str:
    if not isinstance(value, str | int) or isinstance(value, bool):
        raise CalibrationError(f"{where}: must be a string, got {value!r}")
    return str(value)


def _section(where: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise CalibrationError(f"{where}: must be a mapping, got {type(value).__name__}")
    return value


def load_calibration(path: str | Path) -> RigCalibration:
    """Read and check a calibration file; every error names the file and the field."""
    source = str(path)
    try:
        doc = yaml.safe_load(Path(path).read_text())
    except OSError as err:
        raise CalibrationError(f"{source}: cannot read: {err.strerror or err}") from err
    except yaml.YAMLError as err:
        raise CalibrationError(f"{source}: not valid YAML: {err}") from err
    doc = _section(source, doc)
    cameras: dict[str, CameraCalibration] = {}
    for side, raw in _section(f"{source}: cameras", doc.get("cameras", {})).items():
        where = f"{source}: cameras.{side}"
        if side not in SIDES:
            raise CalibrationError(f"{where}: the side must be 'left' or 'right'")
        raw = _section(where, raw)
        try:
            mount = check_pose("finger_from_sensor", raw.get("finger_from_sensor"))
        except ValueError as err:
            raise CalibrationError(f"{where}: {err}") from err
        cameras[side] = CameraCalibration(
            camera_id=_text(f"{where}.camera_id", raw.get("camera_id")),
            finger_from_sensor=mount,
            rotation_sigma_deg=_number(
                f"{where}.rotation_sigma_deg", raw.get("rotation_sigma_deg")
            ),
            translation_sigma_mm=_number(
                f"{where}.translation_sigma_mm", raw.get("translation_sigma_mm")
            ),
            intrinsics={
                k: _number(f"{where}.intrinsics.{k}", v)
                for k, v in _section(f"{where}.intrinsics", raw.get("intrinsics", {})).items()
            },
            reference={
                k: _number(f"{where}.reference.{k}", v)
                for k, v in _section(f"{where}.reference", raw.get("reference", {})).items()
            },
        )
    pressure: dict[str, PressureCalibration] = {}
    for side, raw in _section(f"{source}: pressure", doc.get("pressure", {})).items():
        where = f"{source}: pressure.{side}"
        if side not in SIDES:
            raise CalibrationError(f"{where}: the side must be 'left' or 'right'")
        raw = _section(where, raw)
        pressure[side] = PressureCalibration(
            serial=_text(f"{where}.serial", raw.get("serial")),
            offset_pa=_number(f"{where}.offset_pa", raw.get("offset_pa")),
            offset_sigma_pa=_number(f"{where}.offset_sigma_pa", raw.get("offset_sigma_pa")),
            noise_pa=_number(f"{where}.noise_pa", raw.get("noise_pa", 0.0)),
        )
    return RigCalibration(
        rig=_text(f"{source}: rig", doc.get("rig")),
        date=_text(f"{source}: date", doc.get("date")),
        cameras=cameras,
        pressure=pressure,
        source=source,
    )
