"""Proximity fields: closed forms, numpy vs CasADi vs finite differences, finiteness."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from geometry import fields, objects
from geometry.se3 import make_pose, rotation_about

CYL = fields.CappedCylinder(0.04, 0.1)


def _primitives() -> list[tuple[str, fields.Field]]:
    return [
        ("cylinder", CYL),
        ("box", fields.Box([0.06, 0.04, 0.1])),
        ("sphere", fields.Sphere(0.03)),
        ("capsule", fields.Capsule(0.02, 0.08)),
        ("frustum", fields.Frustum(0.03, 0.015, 0.05)),
        (
            "transformed",
            fields.Transformed(
                fields.Box([0.02, 0.03, 0.04]),
                make_pose(
                    rotation_about(np.array([1.0, 2, 3]), 0.7), np.array([0.01, -0.02, 0.03])
                ),
            ),
        ),
        ("union", fields.Union([CYL, fields.Sphere(0.03)])),
        *[(name, objects.make(name).field) for name in objects.NAMES],
    ]


def _hard_points() -> np.ndarray:
    """A grid through the cylinder's axis, rims, edges and centre, plus far and inside."""
    r, hh = 0.04, 0.05
    special = [
        [0, 0, 0],  # centre
        [0, 0, hh],  # cap centre, on the axis
        [0, 0, 0.3],  # far on the axis
        [0, 0, -0.3],
        [r, 0, hh],  # rim
        [0, -r, -hh],  # rim
        [r, 0, 0],  # side
        [0.0, 0.0, 1e-300],
        [1e-20, 0, 0],
        [1e3, -1e3, 1e3],  # far away
        [0.03, 0.0, 0.049],  # inside, near the cap
        [0.03, 0.0, 0.025],  # inside, equidistant (medial surface)
    ]
    axis = np.array([-0.1, -hh, -0.04, -0.02, 0.0, 0.02, 0.04, hh, 0.1])
    grid = np.array(np.meshgrid(axis, axis, axis)).reshape(3, -1).T
    return np.concatenate([np.array(special, dtype=float), grid])


def test_cylinder_closed_forms() -> None:
    pts = np.array(
        [
            [0.05, 0.0, 0.0],  # 1 cm outside the side
            [0.0, 0.0, 0.07],  # 2 cm above the cap
            [0.07, 0.0, 0.09],  # beyond the rim: corner distance (3, 4) cm -> 5 cm
            [0.0, 0.0, 0.0],  # centre: -min(r, h/2) = -4 cm
            [0.0, 0.03, 0.0],  # inside, 1 cm from the side
            [0.0, 0.0, -0.045],  # inside, 5 mm from the bottom
            [0.04, 0.0, 0.05],  # on the rim
        ]
    )
    want = [0.01, 0.02, 0.05, -0.04, -0.01, -0.005, 0.0]
    np.testing.assert_allclose(CYL.value(pts), want, atol=1e-12)
    _, grad = CYL.value_and_grad(pts)
    np.testing.assert_allclose(grad[0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(grad[1], [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(grad[2], [0.6, 0, 0.8], atol=1e-12)  # toward the rim
    np.testing.assert_allclose(grad[4], [0, 1, 0], atol=1e-12)


def test_other_closed_forms() -> None:
    box = fields.Box([0.02, 0.04, 0.06])
    np.testing.assert_allclose(
        box.value([[0.04, 0, 0], [0.04, 0.06, 0], [0, 0, 0]]), [0.03, np.hypot(0.03, 0.04), -0.01]
    )
    sph = fields.Sphere(0.03)
    np.testing.assert_allclose(sph.value([[0, 0.05, 0], [0, 0, 0]]), [0.02, -0.03])
    cap = fields.Capsule(0.01, 0.1)
    np.testing.assert_allclose(
        cap.value([[0.03, 0, 0.02], [0, 0, 0.08], [0, 0, 0]]), [0.02, 0.02, -0.01]
    )
    fru = fields.Frustum(0.02, 0.02, 0.1)  # a frustum of equal radii is the cylinder
    pts = np.random.default_rng(0).normal(scale=0.05, size=(100, 3))
    np.testing.assert_allclose(
        fru.value(pts), fields.CappedCylinder(0.02, 0.1).value(pts), atol=1e-15
    )
    cone = fields.Frustum(0.03, 0.01, 0.04)
    # Mid height: side at r = 2 cm; slanted side's normal has a z component.
    np.testing.assert_allclose(cone.value([[0.02, 0, 0]]), [0.0], atol=1e-15)
    np.testing.assert_allclose(
        cone.value([[0.02 + 0.01, 0, 0]]), [0.01 / np.sqrt(1.25)], atol=1e-15
    )


@pytest.mark.parametrize(("name", "fld"), _primitives(), ids=[n for n, _ in _primitives()])
def test_finite_everywhere(name: str, fld: fields.Field) -> None:
    pts = _hard_points()
    value, grad = fld.value_and_grad(pts)
    assert np.all(np.isfinite(value)) and np.all(np.isfinite(grad)), name
    # Eikonal (|grad| <= 1) for right-angled slabs; a frustum's slanted rim reaches
    # 1/sin of the rim angle outside, still bounded.
    bound = 1.5 if name in ("frustum", "pet_bottle", "wine_glass") else 1.0 + 1e-9
    assert np.all(np.linalg.norm(grad, axis=1) <= bound), name
    # CasADi: value, gradient and Hessian finite at the same points.
    p = ca.SX.sym("p", 3)
    expr = fld.casadi(p)
    hess, g = ca.hessian(expr, p)
    f = ca.Function("f", [p], [expr, g, hess])
    for pt in pts:
        v, gg, hh = (np.asarray(x) for x in f(pt))
        assert np.all(np.isfinite(v)) and np.all(np.isfinite(gg)) and np.all(np.isfinite(hh)), (
            name,
            pt,
        )


@pytest.mark.parametrize(("name", "fld"), _primitives(), ids=[n for n, _ in _primitives()])
def test_numpy_matches_casadi_and_finite_differences(name: str, fld: fields.Field) -> None:
    rng = np.random.default_rng(3)
    lo, hi = fld.bounds_m()
    pts = rng.uniform(lo - 0.03, hi + 0.03, size=(200, 3))
    value, grad = fld.value_and_grad(pts)
    p = ca.SX.sym("p", 3)
    expr = fld.casadi(p)
    f = ca.Function("f", [p], [expr, ca.gradient(expr, p)])
    cv, cg = f.map(len(pts))(pts.T)
    np.testing.assert_allclose(np.asarray(cv).ravel(), value, atol=1e-14)
    np.testing.assert_allclose(np.asarray(cg).T, grad, atol=1e-10)
    h = 1e-7
    fd = np.stack(
        [(fld.value(pts + h * e) - fld.value(pts - h * e)) / (2 * h) for e in np.eye(3)], axis=1
    )
    # Away from kinks (where a component of delta or the argmin switches), FD agrees.
    agree = np.linalg.norm(fd - grad, axis=1) < 1e-5
    assert agree.mean() > 0.95, (name, agree.mean())


@pytest.mark.parametrize("name", objects.NAMES)
def test_objects(name: str) -> None:
    model = objects.make(name)
    assert model.name == name and model.class_label
    lo, hi = model.bounds_m()
    assert np.all(hi > lo)
    # Axis on z, origin at half height: the bounds are symmetric in z.
    assert abs(lo[2] + hi[2]) < 1e-12
    pts = model.sample_surface(500, np.random.default_rng(0))
    assert pts.shape == (500, 3)
    np.testing.assert_allclose(model.field.value(pts), 0.0, atol=1e-9)
    assert np.all(pts >= lo - 1e-9) and np.all(pts <= hi + 1e-9)


def test_make_overrides_and_errors() -> None:
    big = objects.make("mug", radius_m=0.05)
    assert big.dims_m["radius_m"] == 0.05
    assert big.field.value(np.array([[0.0, -0.05, 0.0]]))[0] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="unknown object"):
        objects.make("teapot")
    with pytest.raises(ValueError, match="colour"):
        objects.make("mug", colour=1.0)
    with pytest.raises(ValueError, match="radius_m"):
        objects.make("mug", radius_m=-1.0)
    with pytest.raises(ValueError, match="radius_m"):
        fields.CappedCylinder(0.0, 0.1)
