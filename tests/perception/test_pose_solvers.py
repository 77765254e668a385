"""IPOPT (with and without jit, both Hessians) and ICP against the same synthetic clouds."""

from __future__ import annotations

import shutil
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from geometry import fields, se3
from geometry.objects import ObjectModel
from perception.pose import jit_cache, metrics, problem, synthetic
from perception.pose.icp import IcpSolver, kabsch
from perception.pose.ipopt import IpoptParams, IpoptSolver, _bucket, _theta_jacobian, jit_available
from perception.pose.lm import LMSolver

CYL = ObjectModel(
    name="cylinder",
    class_label="mug",
    field=fields.CappedCylinder(0.04, 0.095),
    symmetric_about_z=True,
)


def _case(seed: int, n: int = 600):
    rng = np.random.default_rng(seed)
    truth = synthetic.random_grasp_pose(CYL, rng)
    pts, _ = synthetic.grasp_cloud(CYL, truth, n_points=n, noise_m=0.001, rng=rng)
    start = synthetic.tilted_seed(truth, 15.0, rng, offset_m=0.004)
    return truth, pts, se3.invert(start)


def _axis_err(result: problem.FitResult, truth: np.ndarray) -> float:
    return metrics.axis_error_deg(result.tool_from_object, truth, flip_symmetric=True)


@pytest.mark.parametrize("hessian", ["gauss_newton", "exact"])
def test_ipopt_without_jit_recovers_pose_and_matches_lm(hessian: str) -> None:
    truth, pts, seed = _case(1)
    result = IpoptSolver(CYL.field, IpoptParams(jit="off", hessian=hessian)).solve(pts, seed)
    assert result.status == "ok" and result.solver == "ipopt"
    assert _axis_err(result, truth) < 1.0
    assert metrics.offaxis_error_m(result.tool_from_object, truth) < 0.001
    lm = LMSolver(CYL.field).solve(pts, seed)
    # Same problem: IPOPT started at LM's minimum stays there (the costs agree closely).
    # From the seed the two may settle at different slides along the axis: this patch
    # touches a cap barely, and the slide is held by each solver's own gauge.
    again = IpoptSolver(CYL.field, IpoptParams(jit="off", hessian=hessian)).solve(
        pts, lm.object_from_tool
    )
    assert again.cost == pytest.approx(lm.cost, rel=1e-4)
    assert result.cost == pytest.approx(lm.cost, rel=0.02)


def test_jit_fallback_without_a_compiler() -> None:
    assert not jit_available("no-such-cc-for-this-test")
    solver = IpoptSolver(CYL.field, IpoptParams(jit="auto", compiler="no-such-cc-for-this-test"))
    assert solver.use_jit is False
    truth, pts, seed = _case(2)
    assert _axis_err(solver.solve(pts, seed), truth) < 1.0
    with pytest.raises(RuntimeError, match="compiler"):
        IpoptSolver(CYL.field, IpoptParams(jit="on", compiler="no-such-cc-for-this-test"))


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler for CasADi jit")
def test_jit_gives_the_same_answer() -> None:
    truth, pts, seed = _case(3, n=250)
    plain = IpoptSolver(CYL.field, IpoptParams(jit="off")).solve(pts, seed)
    compiled = IpoptSolver(CYL.field, IpoptParams(jit="on")).solve(pts, seed)
    np.testing.assert_allclose(compiled.object_from_tool, plain.object_from_tool, atol=1e-9)
    # The generated sources stay out of the working directory.
    assert not list(Path.cwd().glob("pose*.c")) and not list(Path.cwd().glob("jit_tmp*.c"))


def test_ipopt_gauge_holds_unobservable_directions() -> None:
    rng = np.random.default_rng(4)
    side = CYL.field.sample_surface(4000, rng)
    side = side[np.abs(side[:, 2]) < 0.03][:500]
    truth = synthetic.random_grasp_pose(CYL, rng)
    pts = se3.transform_points(truth, side)
    start = truth @ se3.make_pose(se3.rotation_about(np.array([0, 0, 1.0]), 0.4), [0, 0, 0.01])
    result = IpoptSolver(CYL.field, IpoptParams(jit="off")).solve(pts, se3.invert(start))
    assert result.observable == (True, True, False, True, True, False)
    rel = se3.invert(start) @ result.tool_from_object
    np.testing.assert_allclose(rel, np.eye(4), atol=1e-5)
    assert result.iterations < 30  # no crawl along null directions


def test_theta_jacobian_matches_finite_differences() -> None:
    rng = np.random.default_rng(5)
    pose = se3.make_pose(se3.random_rotation(rng), rng.normal(size=3) * 0.1)
    q0 = se3.quat_from_matrix(pose[:3, :3])
    theta0 = np.concatenate([pose[:3, 3], q0])
    jac = _theta_jacobian(pose)
    h = 1e-7
    for k in range(7):
        d = np.zeros(7)
        d[k] = h
        th = theta0 + d
        # Normalizing q removes only the radial part of dq, which the map sends to zero.
        moved = se3.make_pose(se3.matrix_from_quat(th[3:]), th[:3])
        xi = se3.log_se3(moved @ se3.invert(pose)) / h
        np.testing.assert_allclose(xi, jac[:, k], atol=1e-5)
    np.testing.assert_allclose(jac[:, 3:] @ q0, 0.0, atol=1e-12)


def test_bucket_sizes() -> None:
    assert _bucket(3, 256) == 256
    assert _bucket(10000, 256, frozenset({10000})) == 10000
    assert _bucket(9500, 256, frozenset({10000})) == 10000
    size = _bucket(10000, 256)
    assert 10000 <= size <= 1.2 * 10000 + 256


def test_icp_recovers_pose_and_kabsch_is_exact() -> None:
    rng = np.random.default_rng(6)
    truth_t = se3.make_pose(se3.random_rotation(rng), rng.normal(size=3))
    src = rng.normal(size=(50, 3))
    np.testing.assert_allclose(kabsch(src, se3.transform_points(truth_t, src)), truth_t, atol=1e-9)
    truth, pts, _ = _case(7)
    seed = se3.invert(synthetic.tilted_seed(truth, 5.0, rng, offset_m=0.001))
    result = IcpSolver(CYL.field).solve(pts, seed)
    assert result.solver == "icp" and _axis_err(result, truth) < 2.0


@pytest.mark.parametrize(("true_radius_m", "expect_m"), [(0.045, 0.045), (0.060, 0.048)])
def test_fit_dims_recovers_the_radius_within_its_bounds(true_radius_m, expect_m) -> None:  # noqa: ANN001
    true = ObjectModel(
        name="c",
        class_label="mug",
        field=fields.CappedCylinder(true_radius_m, 0.095),
        symmetric_about_z=True,
    )
    rng = np.random.default_rng(1)
    truth = synthetic.random_grasp_pose(true, rng)
    pts, _ = synthetic.grasp_cloud(true, truth, n_points=1000, noise_m=0.0, rng=rng)
    seed = se3.invert(synthetic.tilted_seed(truth, 5.0, rng, offset_m=0.002))
    solver = IpoptSolver(CYL.field, IpoptParams(jit="off", fit_dims=("radius",)))
    result = solver.solve(pts, seed)
    radius = result.dims_m["radius_m"]
    # 5 mm off the model: recovered within 0.5 mm; 20 mm off: held at the +20% bound.
    assert abs(radius - expect_m) < 5e-4
    assert 0.8 * 0.04 - 1e-12 <= radius <= 1.2 * 0.04 + 1e-12
    if true_radius_m == 0.045:
        assert result.status == "ok" and _axis_err(result, truth) < 0.5
    with pytest.raises(ValueError, match="fit_dims"):
        IpoptSolver(CYL.field, IpoptParams(fit_dims=("width",)))


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_compiled_library_cache_is_reused_atomically(tmp_path: Path) -> None:
    import subprocess
    import sys

    x = ca.SX.sym("x")
    fn = ca.Function("square", [x], [x * x])
    first = jit_cache.library([fn], name="square", compiler="gcc", cache_dir=tmp_path)
    stamp = first.stat().st_mtime_ns
    again = jit_cache.library([fn], name="square", compiler="gcc", cache_dir=tmp_path)
    assert again == first and first.stat().st_mtime_ns == stamp  # found, not rebuilt
    assert float(ca.external("square", str(first))(3.0)) == 9.0
    # Another process finds the same library under the same key.
    code = (
        "import casadi as ca; from perception.pose import jit_cache; x = ca.SX.sym('x'); "
        "print(jit_cache.library([ca.Function('square', [x], [x * x])], name='square', "
        f"compiler='gcc', cache_dir={str(tmp_path)!r}))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == str(first) and first.stat().st_mtime_ns == stamp
    # Another function is another key; nothing but the libraries is left behind.
    jit_cache.library(
        [ca.Function("cube", [x], [x * x * x])], name="square", compiler="gcc", cache_dir=tmp_path
    )
    assert sorted(p.suffix for p in tmp_path.iterdir()) == [".so", ".so"]
    # No compiler: a clear error (callers fall back to CasADi's virtual machine).
    with pytest.raises(RuntimeError, match="not found"):
        jit_cache.library([fn], name="square", compiler="no-such-cc", cache_dir=tmp_path)


@pytest.mark.skipif(shutil.which("gcc") is None, reason="no C compiler")
def test_ipopt_solver_is_compiled_into_the_cache_once(tmp_path: Path) -> None:
    truth, pts, seed = _case(3, n=250)
    prm = IpoptParams(jit="on", cache_dir=str(tmp_path))
    first = IpoptSolver(CYL.field, prm).solve(pts, seed)
    libs = list(tmp_path.glob("pose_ipopt_256-*.so"))
    assert len(libs) == 1 and first.status == "ok" and _axis_err(first, truth) < 1.0
    # A second solver with other options that change the code (the gauge weight is in
    # the generated cost) gets a second library.
    IpoptSolver(CYL.field, IpoptParams(jit="on", cache_dir=str(tmp_path), gauge_weight=2.0)).solve(
        pts, seed
    )
    assert len(list(tmp_path.glob("pose_ipopt_256-*.so"))) == 2
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".build-")]
