"""The proximity-field interface and the finite norms every field is built from."""

from __future__ import annotations

from abc import ABC, abstractmethod

import casadi as ca
import numpy as np

# Floor under every squared norm: sqrt(1e-30) = 1e-15 m, far below any depth noise.
EPS2 = 1e-30


def as_points(points: np.ndarray) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim == 1:
        pts = pts.reshape(1, 3)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    return pts


def safe_norm_np(sq: np.ndarray) -> np.ndarray:
    """sqrt of a squared norm (a sum of squares, so >= 0: the value itself is safe)."""
    return np.sqrt(sq)


def safe_inv(norm: np.ndarray) -> np.ndarray:
    """1 / max(norm, sqrt(EPS2)): finite, and a zero norm's numerator is zero too.

    A gradient ``v / ||v||`` becomes ``v * safe_inv(||v||)``: exactly ``v / ||v||``
    above 1e-15 m, zero at ``v = 0``, and never longer than 1 in between.
    """
    return 1.0 / np.maximum(norm, np.sqrt(EPS2))


def safe_norm_ca(sq: ca.SX | ca.MX) -> ca.SX | ca.MX:
    return ca.if_else(sq > EPS2, ca.sqrt(ca.fmax(sq, EPS2)), 0.0)


class Field(ABC):
    """A proximity field in its own frame. Subclasses implement the three views."""

    @abstractmethod
    def value_and_grad(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Values (N,) and gradients (N, 3) at (N, 3) points of the field's frame."""

    def value(self, points: np.ndarray) -> np.ndarray:
        """Values (N,) at (N, 3) points of the field's frame."""
        return self.value_and_grad(points)[0]

    @abstractmethod
    def casadi(self, p: ca.SX | ca.MX) -> ca.SX | ca.MX:
        """The value as a CasADi expression of a 3x1 symbol ``p``."""

    @abstractmethod
    def bounds_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounding box ``(min_xyz, max_xyz)`` of the surface, metres."""

    @abstractmethod
    def area_m2(self) -> float:
        """Surface area (of the primitive; a union overcounts hidden parts)."""

    @abstractmethod
    def sample_surface(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` points drawn uniformly by area on the surface, (n, 3)."""

    @property
    def revolves_about_z(self) -> bool:
        """True for a body of revolution about the frame's z axis (yaw is invisible)."""
        return False

    @property
    def dims_m(self) -> dict[str, float]:
        """The dimensions a fit may adjust (``casadi_sized``, ``resized``); none by default."""
        return {}

    def casadi_sized(self, p: ca.SX | ca.MX, dims: dict[str, ca.SX | ca.MX]) -> ca.SX | ca.MX:
        """The value with some of :attr:`dims_m` replaced by CasADi symbols."""
        if dims:
            raise ValueError(f"{type(self).__name__} has no adjustable dims, got {sorted(dims)}")
        return self.casadi(p)

    def resized(self, **dims: float) -> Field:
        """The same field with some of :attr:`dims_m` changed."""
        if dims:
            raise ValueError(f"{type(self).__name__} has no adjustable dims, got {sorted(dims)}")
        return self


def merged_dims(fld: Field, dims: dict) -> dict:
    """``fld.dims_m`` updated by ``dims``; unknown names are an error naming them."""
    unknown = sorted(set(dims) - set(fld.dims_m))
    if unknown:
        raise ValueError(
            f"{type(fld).__name__}: unknown dims {unknown}; valid: {sorted(fld.dims_m)}"
        )
    return {**fld.dims_m, **dims}


def positive(name: str, value: float) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value}")
    return value


def casadi_function(field: Field, name: str = "phi", *, symbolic: str = "SX") -> ca.Function:
    """A CasADi function ``p (3x1) -> phi`` of a field (SX by default, MX on request)."""
    sym = ca.SX if symbolic == "SX" else ca.MX
    p = sym.sym("p", 3)
    return ca.Function(name, [p], [field.casadi(p)])
