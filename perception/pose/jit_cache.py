"""Compiled CasADi functions cached on disk, per user, reused across processes and runs.

CasADi's own ``jit`` compiles again in every process (1-6 s per solver at 10k points).
Here the functions an IPOPT solver needs are generated as C once, and the shared
library is kept under a key made of everything that changes the machine code: the
generated source itself (so the problem's shape, the field, the point count and the
options are all in it), the CasADi version, the compiler's identity (its path and
``--version`` line) and the flags. A later process, or another graph, finds the library
and only loads it.

- Directory: ``cache_dir`` when given, else ``$XDG_CACHE_HOME/softbubble/casadi``, else
  ``~/.cache/softbubble/casadi``.
- Atomic: the source is compiled in a private temporary directory inside the cache
  directory (``.build-PID-*``), and the library is moved into place with
  ``os.replace``; concurrent processes compiling the same key both succeed, and the last
  rename wins with an identical file. The temporary directory is removed whatever
  happens, and when the process is killed during a compile (SIGKILL, a stopped graph),
  the next compile removes the build folders of processes that are gone.
- No compiler (or a broken one): :func:`compiler_id` is ``None`` and callers fall back to
  CasADi's virtual machine (same answer, slower).
"""

from __future__ import annotations

import functools
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import casadi as ca


def default_dir() -> Path:
    """The per-user cache directory (``$XDG_CACHE_HOME`` honoured)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "softbubble" / "casadi"


@functools.cache
def compiler_id(compiler: str) -> str | None:
    """``"<path> <first --version line>"`` of a C compiler, or ``None`` if there is none."""
    path = shutil.which(compiler)
    if path is None:
        return None
    try:
        out = subprocess.run(
            [path, "--version"], capture_output=True, text=True, timeout=30, check=True
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    lines = out.splitlines()
    return f"{path} {lines[0] if lines else ''}"


def cache_key(source: str, compiler: str, flags: tuple[str, ...]) -> str:
    """The key of one library: source, CasADi version, compiler identity and flags."""
    digest = hashlib.sha256()
    version: str = ca.__version__  # type: ignore[attr-defined]  # not in casadi's stub
    for part in (version, str(compiler_id(compiler)), " ".join(flags), source):
        digest.update(part.encode())
        digest.update(b"\0")
    return digest.hexdigest()[:24]


def library(
    functions: list[ca.Function],
    *,
    name: str,
    compiler: str,
    flags: tuple[str, ...] = ("-O2",),
    cache_dir: str | os.PathLike[str] | None = None,
) -> Path:
    """The path of a shared library holding ``functions``, compiled now or found cached.

    Raises:
        RuntimeError: no working compiler, or the compile failed (its output included).
    """
    if compiler_id(compiler) is None:
        raise RuntimeError(f"C compiler {compiler!r} not found or not working")
    gen = ca.CodeGenerator(f"{name}.c", {"with_header": False})
    for fn in functions:
        gen.add(fn)
    source = gen.dump()
    directory = Path(cache_dir) if cache_dir else default_dir()
    path = directory / f"{name}-{cache_key(source, compiler, flags)}.so"
    if path.is_file():
        return path
    directory.mkdir(parents=True, exist_ok=True)
    remove_stale_builds(directory)
    with tempfile.TemporaryDirectory(dir=directory, prefix=f"{BUILD_PREFIX}{os.getpid()}-") as tmp:
        src = Path(tmp) / f"{name}.c"
        src.write_text(source)
        out = Path(tmp) / f"{name}.so"
        cmd = [compiler, "-shared", "-fPIC", *flags, str(src), "-o", str(out)]
        done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr.strip()[-2000:]}")
        os.replace(out, path)
    return path


BUILD_PREFIX = ".build-"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


def remove_stale_builds(directory: Path) -> list[Path]:
    """Remove the build folders of processes that are gone (killed during a compile);
    returns them. A folder without a process id (an older layout) counts as gone."""
    removed = []
    for folder in directory.glob(f"{BUILD_PREFIX}*"):
        pid = folder.name.removeprefix(BUILD_PREFIX).partition("-")[0]
        if pid.isdigit() and _alive(int(pid)):
            continue
        shutil.rmtree(folder, ignore_errors=True)
        removed.append(folder)
    return removed


@functools.cache
def jit_available(compiler: str = "gcc") -> bool:
    """Whether ``compiler`` builds a CasADi function that loads and runs here.

    The probe is compiled in a temporary directory that is removed again.
    """
    if compiler_id(compiler) is None:
        return False
    x = ca.SX.sym("x")
    probe = ca.Function("jit_probe", [x], [x * x])
    with tempfile.TemporaryDirectory(prefix="pose_jit_probe_") as tmp:
        try:
            lib = library([probe], name="jit_probe", compiler=compiler, cache_dir=tmp)
            return float(ca.external("jit_probe", str(lib))(3.0)) == 9.0
        except RuntimeError:
            return False
