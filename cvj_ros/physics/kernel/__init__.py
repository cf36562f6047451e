"""Compiled physics core: scene as data, numba kernels, compiled steppers.

Importing this package does not import numba; ``steppers_nb`` (and core-A's
``rhs_nb``) do. Before that, :func:`configure_cache` points numba's on-disk cache
at a writable place: numba's default (``__pycache__`` next to the sources) when
the install is writable, else a user cache directory, so read-only site-packages
and colcon install trees work. ``NUMBA_CACHE_DIR`` set by the user always wins.

numba checks a cached function against its own source file only, so code that inlines
functions of other modules (the steppers inline rhs_nb, which inlines the joint and source
formulas) would stay stale after an edit of those modules. :func:`drop_stale_cache` keeps
a digest of every physics source beside the cache (hashing ~40 files costs ~2 ms per
process); when it changed, it deletes the cache files of exactly the modules whose import
closure inside ``cvj_ros/physics`` holds a changed file (a compiled function can only
inline what its module reaches through imports), so an edit of ``joints/hooke.py``
recompiles the Hooke formula and what imports it (joints_nb, rhs_nb, the steppers, ...),
an edit of ``simulate.py`` (imported by no compiled module) recompiles nothing.

:func:`load_cached` loads a cached entry point without numba's full target
initialisation (docs/solvers.md "Start-up"): numba's own cache load first runs
``CPUContext.refresh()``, which imports and registers every numba implementation module
(and, through ``numba.np.arraymath``'s BLAS probe, ``scipy.linalg``): measured ~0.55 s
of a ~1.7 s warm ``cvj-sim simulate``, for code that is already compiled.

Compilation is per entry point and on first use: a run compiles the functions it calls
(its method's stepper, the outputs, the monitor's windows, ...) and nothing else.
:func:`compiling` announces each compile on stderr when ``CVJ_COMPILE_NOTICE=1`` (``cvj-sim``
sets it): ``cvj_ros: compiling the physics kernel: dopri5_advance (first use; cached
afterwards)`` and ``cvj_ros: compiled dopri5_advance in 9.1 s``.
"""
from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

PHYSICS_DIR = Path(__file__).resolve().parents[1]
STAMP_NAME = 'cvj_kernel_sources.sha256'
# per-module digests of the import closures (drop_stale_cache), beside STAMP_NAME
CLOSURES_NAME = 'cvj_kernel_closures.json'


def choose_cache_dir(package_dir: str, env: dict, writable) -> str | None:
    """Numba cache directory to use: None = numba's default (next to the sources).

    package_dir: this package's directory; env: the environment mapping;
    writable(path) -> bool. User cache: $XDG_CACHE_HOME/cvj_ros/numba, else
    ~/.cache/cvj_ros/numba (HOME from env)."""
    if env.get('NUMBA_CACHE_DIR'):
        return env['NUMBA_CACHE_DIR']
    pycache = os.path.join(package_dir, '__pycache__')
    if writable(pycache if os.path.isdir(pycache) else package_dir):
        return None
    base = env.get('XDG_CACHE_HOME') or os.path.join(env.get('HOME', os.path.expanduser('~')),
                                                     '.cache')
    return os.path.join(base, 'cvj_ros', 'numba')


def configure_cache() -> None:
    """Set NUMBA_CACHE_DIR before numba is imported when the install is read-only."""
    path = choose_cache_dir(os.path.dirname(os.path.abspath(__file__)), os.environ,
                            lambda p: os.access(p, os.W_OK))
    if path is not None and not os.environ.get('NUMBA_CACHE_DIR'):
        os.environ['NUMBA_CACHE_DIR'] = path


def sources_digest(physics_dir: Path = PHYSICS_DIR) -> str:
    """sha256 over the names and bytes of every .py file under cvj_ros/physics."""
    h = hashlib.sha256()
    for path in sorted(physics_dir.rglob('*.py')):
        h.update(str(path.relative_to(physics_dir)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _cache_files(cache_dir: str | None, physics_dir: Path) -> list[Path]:
    """numba index/data files of this package's compiled functions."""
    if cache_dir is None:   # numba's default: __pycache__ beside each source file
        roots = [p for p in physics_dir.rglob('__pycache__') if p.is_dir()]
    else:
        roots = [Path(cache_dir)] if Path(cache_dir).is_dir() else []
    out: list[Path] = []
    for root in roots:
        for pattern in ('*.nbi', '*.nbc'):
            out.extend(p for p in root.rglob(pattern)
                       if cache_dir is None or 'cvj_ros' in str(p))
    return out


def _imports(path: Path, physics_dir: Path) -> set[Path]:
    """Files under ``physics_dir`` that module ``path`` imports (absolute
    ``cvj_ros.physics...`` or relative imports, at any depth of the module; a name imported
    from a package counts as its submodule when there is one)."""
    import ast
    tree = ast.parse(path.read_bytes())
    package = path.parent
    out: set[Path] = set()

    def add(base: Path, parts: list[str]) -> None:
        target = base.joinpath(*parts) if parts else base
        for cand in (target.with_suffix('.py'), target / '__init__.py'):
            if cand.is_file() and physics_dir in cand.parents:
                out.add(cand)
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith('cvj_ros.physics'):
                    add(physics_dir, alias.name.split('.')[2:])
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package
                for _ in range(node.level - 1):
                    base = base.parent
                mod = node.module.split('.') if node.module else []
            elif node.module and node.module.startswith('cvj_ros.physics'):
                base, mod = physics_dir, node.module.split('.')[2:]
            else:
                continue
            add(base, mod)
            for alias in node.names:
                add(base, [*mod, alias.name])
    return out


def closure_digests(physics_dir: Path = PHYSICS_DIR) -> dict[str, str]:
    """Per physics module (path relative to ``physics_dir``): sha256 over the names and
    bytes of the module and of every physics file it imports, transitively."""
    files = sorted(physics_dir.rglob('*.py'))
    own = {f: hashlib.sha256(f.read_bytes()).digest() for f in files}
    direct: dict[Path, set[Path]] = {}
    for f in files:
        try:
            direct[f] = _imports(f, physics_dir)
        except (SyntaxError, ValueError):
            direct[f] = set(files)          # unreadable: depends on everything
    out: dict[str, str] = {}
    for f in files:
        seen, todo = {f}, [f]
        while todo:
            for dep in direct.get(todo.pop(), ()):
                if dep not in seen:
                    seen.add(dep)
                    todo.append(dep)
        h = hashlib.sha256()
        for dep in sorted(seen):
            h.update(str(dep.relative_to(physics_dir)).encode())
            h.update(own[dep])
        out[str(f.relative_to(physics_dir))] = h.hexdigest()
    return out


def _source_of(cache_file: Path, cache_dir: str | None, physics_dir: Path) -> str | None:
    """The physics module (relative path) a numba cache file belongs to: its name starts
    with the module's name; its directory is the module's ``__pycache__`` (numba's default)
    or, under NUMBA_CACHE_DIR, ``<source directory name>_<hash>``."""
    module = cache_file.name.split('.', 1)[0]
    if cache_dir is None:
        rel = cache_file.parent.parent.relative_to(physics_dir)
    else:
        top = cache_file.parent.name.rsplit('_', 1)[0]
        rel = Path('.') if top == physics_dir.name else Path(top)
    return str(rel / f'{module}.py') if (physics_dir / rel / f'{module}.py').is_file() else None


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f'{path.name}.tmp{os.getpid()}')
    tmp.write_text(text)
    os.replace(tmp, path)


def drop_stale_cache(cache_dir: str | None = None, physics_dir: Path = PHYSICS_DIR) -> bool:
    """Delete the numba cache files of the physics modules whose import closure changed
    since they were written (all of them when that is not known: no record yet, or a
    cache file of a module that no longer exists); returns True when it deleted any.
    Never raises (a cache that cannot be cleaned is numba's to rebuild or to ignore)."""
    import json
    try:
        stamp_dir = Path(cache_dir) if cache_dir else physics_dir / 'kernel' / '__pycache__'
        stamp = stamp_dir / STAMP_NAME
        digest = sources_digest(physics_dir)
        old = stamp.read_text().strip() if stamp.is_file() else None
        if old == digest:
            return False
        closures = closure_digests(physics_dir)
        record = stamp_dir / CLOSURES_NAME
        try:
            before = json.loads(record.read_text()) if old is not None else {}
        except (OSError, ValueError):
            before = {}
        files = []
        for f in _cache_files(cache_dir, physics_dir):
            src = _source_of(f, cache_dir, physics_dir)
            if src is None or before.get(src) != closures.get(src):
                files.append(f)
                f.unlink(missing_ok=True)
        stamp_dir.mkdir(parents=True, exist_ok=True)
        _write_atomic(record, json.dumps(closures, sort_keys=True))
        _write_atomic(stamp, digest + '\n')
        return bool(files)
    except OSError:
        return False


def load_cached(dispatcher: Any, args: Sequence[Any]) -> Callable[..., Any] | None:
    """Entry point of ``dispatcher`` (a numba ``@njit(cache=True)`` function) for the
    types of ``args``, loaded from the disk cache; None when it cannot be loaded this
    way (no cache entry, caching off, a numba without these internals, any error): the
    caller then calls the dispatcher as usual, which compiles or loads it numba's way.

    Same steps as numba 0.68's ``Dispatcher.compile`` on a cache hit (the overload is
    registered with the dispatcher, so later calls through it dispatch to it directly)
    except ``CPUContext.refresh()``: the typing and lowering registries serve compilation
    only. What a cached library needs at run time is installed all the same: the C helper
    and exception symbols by the target context's construction, the NRT symbols by
    ``rtsys.initialize`` (called here, as ``refresh`` would), anything else by numba's own
    ``reload_init`` hooks stored in the cache entry. A later cache miss compiles through
    numba's normal path, which refreshes first. ``CVJ_KERNEL_LOAD=numba`` disables this
    (numba's own load everywhere, e.g. to compare bytes)."""
    if os.environ.get('CVJ_KERNEL_LOAD', '').strip().lower() == 'numba':
        return None
    try:
        from numba.core.compiler_lock import global_compiler_lock
        from numba.core.runtime import rtsys
        sig = tuple(dispatcher.typeof_pyval(a) for a in args)
        with global_compiler_lock:
            existing = dispatcher.overloads.get(sig)
            if existing is not None:
                return existing.entry_point
            ctx = dispatcher.targetctx
            rtsys.initialize(ctx)
            cres = dispatcher._cache._load_overload(sig, ctx)   # load_overload minus refresh
            if cres is None or cres.objectmode:
                return None
            dispatcher._cache_hits[sig] += 1
            ctx.insert_user_function(cres.entry_point, cres.fndesc, [cres.library])
            dispatcher.add_overload(cres)
            return cres.entry_point
    except Exception:   # noqa: BLE001 - numba's normal path decides (and reports) instead
        return None


@contextlib.contextmanager
def compiling(dispatcher: Any) -> Iterator[None]:
    """Around a call that compiles ``dispatcher`` (its disk cache had no entry): one line on
    stderr before and one after, with the wall time, when ``CVJ_COMPILE_NOTICE=1`` - a cold
    compile takes seconds to a minute and the user should know why nothing happens."""
    if os.environ.get('CVJ_COMPILE_NOTICE', '') != '1':
        yield
        return
    name = getattr(getattr(dispatcher, 'py_func', None), '__name__', None) or str(dispatcher)
    print(f'cvj_ros: compiling the physics kernel: {name} (first use; cached afterwards)',
          file=sys.stderr, flush=True)
    t0 = time.perf_counter()
    yield
    print(f'cvj_ros: compiled {name} in {time.perf_counter() - t0:.1f} s', file=sys.stderr, flush=True)


def entry_point(dispatcher: Any, args: Sequence[Any]) -> Callable[..., Any]:
    """The compiled entry point of ``dispatcher`` for the types of ``args`` (loaded from the
    cache, or compiled by a first call through the dispatcher), or the dispatcher itself
    when numba offers none. For a caller that calls with the same argument types every
    time (the coupling node's per-exchange joint states and wrenches): the dispatcher's
    typing of 7-9 array arguments costs a few us per call, inside a running loop more."""
    entry = load_cached(dispatcher, args)
    if entry is not None:
        return entry
    with compiling(dispatcher) if _will_compile(dispatcher) else contextlib.nullcontext():
        dispatcher(*args)
    try:
        return dispatcher.overloads[tuple(dispatcher.typeof_pyval(a) for a in args)].entry_point
    except (KeyError, AttributeError, ValueError):
        return dispatcher


_ENTRIES: dict[Any, Callable[..., Any]] = {}


def _will_compile(dispatcher: Any) -> bool:
    """After :func:`load_cached` found nothing: whether calling ``dispatcher`` compiles
    (no overload in memory and not ``CVJ_KERNEL_LOAD=numba``, under which numba's own load
    may still hit the cache)."""
    if os.environ.get('CVJ_KERNEL_LOAD', '').strip().lower() == 'numba':
        return False
    return not getattr(dispatcher, 'overloads', None)


def entry_point_once(dispatcher: Any, args: Sequence[Any]) -> Callable[..., Any]:
    """:func:`entry_point`, found once per process and dispatcher and kept. Only for
    callers that pass the same argument types on every call (arrays they allocate
    themselves: float64/int64, C-contiguous, the same ndim): an entry point does not check
    types. ``Simulation.run``'s compiled outputs: the dispatcher's typing of 12 arguments
    cost ~20 us per run, a tenth of a loose-tolerance kavz685_lever run."""
    entry = _ENTRIES.get(dispatcher)
    if entry is None:
        entry = _ENTRIES[dispatcher] = entry_point(dispatcher, args)
    return entry


configure_cache()
drop_stale_cache(os.environ.get('NUMBA_CACHE_DIR') or None)
