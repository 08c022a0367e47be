"""Warm start without tracing: compiled programs kept as exported StableHLO on disk.

JAX's persistent compilation cache (:mod:`jaxform.cache`) saves the XLA compile, but a
second run still traces and lowers every program to compute the cache key: for the seed
scene's step chunk that is ~4 s of a ~6 s warm first call.  :func:`call` keeps the
traced and lowered program itself (``jax.export``, serialized StableHLO) in the cache
directory, under a key of everything that shapes it:

* the program's name and its static arguments, as their ``repr`` (frozen dataclasses of
  settings: the :class:`jaxform.stepping.Stepper`, the chunk length), or for a program
  that closes over a whole problem (a design problem's gradient) the problem's content
  (:func:`fingerprint`: every field, arrays by their bytes);
* the tree structure, shapes and dtypes of its traced arguments;
* the source of every jaxform module (a changed line is a new key), the jax, jaxlib and
  klujax versions, the backend and the x64 flag.

A stored program is loaded and called through a small wrapper program (traced in
milliseconds; its XLA compile comes from the persistent cache), so a warm first call
skips the tracing and lowering.  Where that wrapper was compiled in this process, its
compiled executable is kept too (``{key}-{machine_tag}.xla``: the CPU and the XLA flags
it was compiled for), and a later process loads it directly, without deserializing the
exported program, lowering the wrapper or hashing it for JAX's cache.  What a program
reads must come in through its arguments or be described by ``static``: a closed-over
array that the description left out would be baked in unseen by the key.

Static settings whose ``repr`` shows an object address (no stable description), a
program that cannot be exported, no cache directory (``jaxform.cache`` off) or
``JAXFORM_PROGRAM_STORE=off`` in the environment: the function is called as it is,
traced as always.  The files are trusted code, like the
compilation cache (the output tree structure is a pickle).
"""

from __future__ import annotations

import dataclasses
import enum
import gc
import hashlib
import os
import pickle
import re
import tempfile
import threading
import time
import warnings
import zlib
from functools import cache
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax import export
from jax.experimental import serialize_executable

from jaxform.cache import OFF, version_tag
from jaxform.host_memory import give_back_after
from jaxform.linear import register_ffi_targets
from jaxform.xla_options import jit

SUBDIR = "exported"
ENV_VAR = "JAXFORM_PROGRAM_STORE"  # off / 0 / none / false / no: trace every run
_loaded: dict[str, tuple] = {}  # key -> (compiled wrapper, output tree) in this process
_refused: set[str] = set()  # keys whose program could not be exported
# Each compiled CPU program holds a few memory maps of the process (its code and data
# sections) for as long as something keeps it; Linux stops a process at vm.max_map_count
# maps (65530 by default), and XLA aborts when an allocation then fails.  A process that
# compiles hundreds of programs (a test worker, a design over many meshes) lets them go
# once it holds this share of the limit (release_if_crowded).
MAP_SHARE = 0.5
# Before a new program (a stored one, a replay's mesh or reverse pass, a design's
# evaluation) the process makes room in levels (make_room): past MAP_SHARE the stored
# programs go (a forward run's step chunks, read back from disk in a fraction of a
# second), JAX's compiled executables only past CLEAR_SHARE (its traces stay) and its
# traces only where that is not enough: a gradient replay needs its programs again at its
# next evaluation, and the shipped two-stage disk's replay alone holds ~75 % of the limit.
CLEAR_SHARE = 0.85
# Between MAP_SHARE and CLEAR_SHARE the stored programs go again only once the share has
# grown this much since they last went: where JAX's programs hold more than MAP_SHARE (a
# design's gradient), a forward run's stored programs would otherwise go at each new one
# and be read back again and again.
STORED_STEP = 0.1
_stored_floor = 0.0  # the share just after the stored programs last went
# JAX's compiled executables also go where the share plus the largest rise seen between
# two readings would pass this: the next rise may be as large.  A design of the two-stage
# disk on 0.35 mm elements rose from 17 000 to 49 000 maps within 30 s (a new plan's
# forward run and gradient programs) and was stopped by the kernel from 80 % of the limit
# (LLVM "Cannot allocate memory", then a segfault) before the share passed CLEAR_SHARE.
HEADROOM_SHARE = 0.95
_warned_limit = False  # MapLimitWarning given (once a process)


class MapLimitWarning(ResourceWarning):
    """The process holds so many memory maps, after letting its programs go, that the
    largest rise seen would pass the kernel's limit (``vm.max_map_count``)."""


_last_share: float | None = None  # the share at make_room's last reading, after its release
_largest_rise = 0.0  # the largest rise of the share from one reading to the next
# make_room reads the process's map table (/proc/self/maps: 2-10 ms in a process holding
# hundreds of programs) at most once in this many seconds: no compile adds maps that fast,
# and a loop of cheap evaluations (a sampling optimizer on a closed form) would otherwise
# spend most of its time there.
ROOM_CHECK_INTERVAL_S = 0.25
_room_checked_at = -float("inf")  # _clock() at make_room's last reading
_clock = time.monotonic
_MAPS = Path("/proc/self/maps")
_MAP_LIMIT = Path("/proc/sys/vm/max_map_count")


_ROOT = Path(__file__).resolve().parent  # the package whose source keys the programs


def _source_files() -> list[Path]:
    return sorted(_ROOT.rglob("*.py"))


def _source_stamp() -> tuple:
    """(path, size, modification time) of each source file: cheap to compare."""
    stamp = []
    for path in _source_files():
        try:
            st = path.stat()
        except OSError:
            continue
        stamp.append((str(path), st.st_size, st.st_mtime_ns))
    return tuple(stamp)


@cache
def _source_at_start() -> tuple[str, tuple]:
    """(sha256 of the source of every jaxform module, their stamp), read once, when this
    module is imported (the modules imported before it were loaded from that source)."""
    stamp = _source_stamp()
    h = hashlib.sha256()
    for path in _source_files():
        h.update(str(path.relative_to(_ROOT)).encode())
        h.update(path.read_bytes())
    return h.hexdigest(), stamp


def code_fingerprint() -> str:
    """sha256 of the source of every jaxform module (the package's .py files), as it was
    when this process started to use the store."""
    return _source_at_start()[0]


def source_changed() -> bool:
    """Whether a jaxform source file changed on disk since :func:`code_fingerprint` read
    them.  The modules this process runs may then differ from the source the key names
    (one imported before the change, another after), so it neither loads nor stores
    programs from then on: a program traced from edited code must not be kept under the
    key of the code it replaced, nor the reverse."""
    return _source_stamp() != _source_at_start()[1]


_source_at_start()  # read at import (see its docstring)


def store_dir() -> Path | None:
    """Where the exported programs go: ``exported/`` beside JAX's compilation cache (None
    when the cache is off, or the environment sets ``JAXFORM_PROGRAM_STORE=off``)."""
    if os.environ.get(ENV_VAR, "on").strip().lower() in OFF:
        return None
    base = jax.config.jax_compilation_cache_dir
    return Path(base) / SUBDIR if base else None


@cache
def _map_limit() -> int | None:
    try:
        return int(_MAP_LIMIT.read_text())
    except (OSError, ValueError):
        return None  # not Linux: no such limit to watch


def map_share() -> float:
    """The share of the kernel's limit on memory maps (``vm.max_map_count``) that this
    process uses now; 0.0 where the limit is unknown."""
    limit = _map_limit()
    if not limit:
        return 0.0
    try:
        with _MAPS.open("rb") as f:
            return f.read().count(b"\n") / limit
    except OSError:
        return 0.0


def release_programs() -> None:
    """Let go of every compiled program this process keeps: the stored programs loaded
    here and JAX's in-memory caches (a program needed again comes from the persistent
    cache, or is compiled again where there is none)."""
    global _stored_floor
    jax.clear_caches()
    if not release_stored_programs():  # which collects the garbage itself
        gc.collect()
    _stored_floor = 0.0


def release_compiled() -> bool:
    """Let go of JAX's compiled executables (its in-memory executable caches: the C++
    dispatch caches, the lowered computations that hold their executables, the compiled
    programs), keeping its traced and lowered programs: a program needed again is only
    compiled again (from the persistent cache where there is one), not traced.  True when
    this JAX has those caches (else nothing happens: :func:`release_programs` then lets go
    of everything)."""
    try:
        from jax._src import pjit
        from jax._src.interpreters import pxla
        from jax._src.lib import _jax

        caches = (pjit._cpp_pjit_cache_fun_only, pjit._cpp_pjit_cache_explicit_attributes)
        lowered, compiled = pjit._pjit_lower, pxla._cached_compilation
        all_cpp = _jax.PjitFunctionCache
    except (ImportError, AttributeError):
        return False
    for c in caches:
        c.clear()
    all_cpp.clear_all()
    lowered.cache_clear()
    compiled.cache_clear()
    gc.collect()
    return True


def release_stored_programs() -> bool:
    """Let go of the stored programs loaded in this process (:func:`call`), keeping JAX's
    own caches (the traced and compiled programs of a gradient replay); True when there
    were any."""
    if not _loaded:
        return False
    _loaded.clear()
    gc.collect()
    return True


def make_room() -> str | None:
    """Before a new program: past :data:`MAP_SHARE` of the memory-map limit (and
    :data:`STORED_STEP` above where the last such release left it) the stored programs
    go; past :data:`CLEAR_SHARE`, or where the largest rise of the share seen from one
    reading to the next would take it past :data:`HEADROOM_SHARE`, the stored programs,
    then JAX's compiled executables
    (:func:`release_compiled`: its traced programs stay, so that a program needed again,
    e.g. a gradient replay's on a new plan whose meshes share its buckets, is compiled
    from the persistent cache but not traced again), and everything where that is not
    enough.  Below it a gradient replay's own programs stay, so that its next evaluation
    on the same plan traces and compiles nothing.  Within :data:`ROOM_CHECK_INTERVAL_S`
    of its last reading it reads nothing.  Returns what it let go (``"stored"``,
    ``"compiled"``, ``"all"``) or None."""
    global _stored_floor, _room_checked_at, _last_share, _largest_rise
    now = _clock()
    if now - _room_checked_at < ROOM_CHECK_INTERVAL_S:
        return None
    _room_checked_at = now
    share = map_share()
    if _last_share is not None:
        _largest_rise = max(_largest_rise, share - _last_share)
    _last_share = share

    def tight(share):
        return share > CLEAR_SHARE or share + _largest_rise > HEADROOM_SHARE

    if not tight(share) and share <= max(MAP_SHARE, _stored_floor + STORED_STEP):
        return None
    done = None
    if release_stored_programs():
        done, share = "stored", map_share()
        _stored_floor = share
    if tight(share) and release_compiled():
        done, share = "compiled", map_share()
    if tight(share):
        release_programs()
        done, share = "all", map_share()
    _last_share = share
    if share + _largest_rise > 1.0:
        _warn_limit(share)
    return done


def _warn_limit(share: float) -> None:
    """:class:`MapLimitWarning`, once a process: what the process holds, what a program
    took, and the remedy (the kernel's limit raised)."""
    global _warned_limit
    if _warned_limit:
        return
    _warned_limit = True
    warnings.warn(
        f"this process holds {share:.0%} of the kernel's memory-map limit "
        f"(vm.max_map_count = {_map_limit()}) after letting its compiled programs go, and "
        f"one reading to the next has added up to {_largest_rise:.0%} of it: the next "
        "programs may not fit (LLVM 'Cannot allocate memory', and the process stops); "
        "raise the limit, e.g. sysctl -w vm.max_map_count=262144",
        MapLimitWarning,
        stacklevel=3,
    )


def release_if_crowded(share: float | None = None) -> bool:
    """:func:`release_programs` when the process holds more than ``share`` (default
    :data:`MAP_SHARE`) of its memory map limit; True when it did (between tests of a
    worker: the next test needs other programs)."""
    if map_share() <= (MAP_SHARE if share is None else share):
        return False
    release_programs()
    return True


class NotStorable(Exception):
    """A program that ``jax.export`` cannot export (it runs unstored)."""


class Unstable(TypeError):
    """An object with no stable description (:func:`fingerprint`)."""


def fingerprint(obj) -> str | None:
    """A description of ``obj`` by content, stable across processes: dataclasses by their
    class and fields, containers by their items, arrays by their shape, dtype and bytes
    (sha256), numbers, strings, None and Enum members by value; None for anything else (a
    function, an object whose state is not in its fields), which then is not stored."""
    h = hashlib.sha256()
    try:
        _feed(h, obj)
    except Unstable:
        return None
    return h.hexdigest()


def _feed(h, obj) -> None:
    if obj is None or isinstance(obj, (bool, int, float, complex, str, bytes)):
        h.update(f"{type(obj).__name__}:{obj!r};".encode())
    elif isinstance(obj, enum.Enum):
        h.update(f"{type(obj).__qualname__}.{obj.name};".encode())
    elif isinstance(obj, (np.ndarray, np.generic, jax.Array)):
        a = np.asarray(obj)
        h.update(f"array{a.shape}{a.dtype}:".encode())
        h.update(hashlib.sha256(np.ascontiguousarray(a).tobytes()).digest())
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(f"{type(obj).__module__}.{type(obj).__qualname__}(".encode())
        for f in dataclasses.fields(obj):
            h.update(f"{f.name}=".encode())
            _feed(h, getattr(obj, f.name))
        h.update(b")")
    elif isinstance(obj, (tuple, list)):
        h.update(f"{type(obj).__name__}[".encode())
        for item in obj:
            _feed(h, item)
        h.update(b"]")
    elif isinstance(obj, dict):
        h.update(b"{")
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
        h.update(b"}")
    else:
        raise Unstable(type(obj).__qualname__)


def program_key(name: str, static: str | None, args) -> str | None:
    """The key of program ``name`` with static settings ``static`` (a repr or a
    :func:`fingerprint`) on ``args`` (pytrees of arrays); None where the settings have no
    stable description."""
    if static is None or re.search(r" at 0x[0-9a-fA-F]+", static):
        return None
    leaves, tree = jax.tree_util.tree_flatten(args)
    h = hashlib.sha256()
    parts = (name, static, repr(tree), version_tag(), code_fingerprint(),
             jax.default_backend(), str(jax.config.jax_enable_x64))  # fmt: skip
    for part in parts:
        h.update(part.encode())
        h.update(b"\0")
    for leaf in leaves:
        h.update(f"{jnp.shape(leaf)}{jnp.result_type(leaf)};".encode())
    return h.hexdigest()


# custom-call targets with no cross-version guarantee that jaxform's programs call (klujax's
# and jaxform's own FFI calls): the key holds the versions that make them, so they are safe
# to store.  A target missing here is learnt from the export's refusal (one more trace).
_TARGETS: set[str] = set()


@cache
def _known_targets() -> frozenset[str]:
    """The FFI targets klujax registers (read from its module's source) and jaxform's."""
    from jaxform import klu_free, pardiso

    names = {klu_free.TARGET, *pardiso.TARGETS.values()}
    try:
        import klujax

        source = Path(klujax.__file__).read_text()
        names |= set(re.findall(r'register_ffi_target\(\s*"(\w+)"', source))
    except (ImportError, OSError):
        pass
    return frozenset(names)


def _export(fn, leaves, tree):
    """(exported program of fn on the flat leaves, the output tree structure)."""
    holder = {}

    def flat(*lv):
        out = fn(*jax.tree_util.tree_unflatten(tree, lv))
        out_leaves, holder["tree"] = jax.tree_util.tree_flatten(out)
        return out_leaves

    jitted = jax.jit(flat)
    _TARGETS.update(_known_targets())
    for attempt in range(2):
        checks = [export.DisabledSafetyCheck.custom_call(n) for n in sorted(_TARGETS)]
        try:
            exported = export.export(jitted, disabled_checks=checks)(*leaves)
            return exported, holder["tree"]
        except ValueError as err:
            found = set(re.findall(r"custom_call @(\w+)", str(err))) - _TARGETS
            if attempt or not found:
                raise
            _TARGETS.update(found)
    raise AssertionError("unreachable")


def _write(path: Path, data: bytes) -> None:
    """Write atomically (a partly written file is never read as a program)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _prepared(key: str, fn, leaves, tree):
    """(compiled wrapper, output tree) of program ``key``: from this process, from the
    disk, or exported now (and stored)."""
    if key in _loaded:
        return _loaded[key]
    if source_changed():
        raise NotStorable(key)  # edited under this process: run it traced (source_changed)
    make_room()  # before a new program adds its maps
    register_ffi_targets()  # a loaded program calls them without being traced here
    folder = store_dir()
    blob_path, tree_path = folder / f"{key}.bin", folder / f"{key}.tree"
    exe_path = folder / f"{key}-{machine_tag()}.xla"
    if exe_path.is_file() and tree_path.is_file():
        entry = _read_executable(exe_path, tree_path)
        if entry is not None:
            _loaded[key] = entry
            return entry
    exported = None
    if blob_path.is_file() and tree_path.is_file():
        try:
            exported = export.deserialize(bytearray(blob_path.read_bytes()))
            out_tree = pickle.loads(tree_path.read_bytes())
        except Exception:  # a damaged or foreign file: export it again
            exported = None
    if exported is None:
        try:
            exported, out_tree = _export(fn, leaves, tree)
        except (ValueError, TypeError, NotImplementedError, ImportError) as err:
            # jax.export refuses the program (a primitive or custom call it cannot
            # serialize; ImportError: no flatbuffers serializer); an error of fn itself
            # comes back when call() runs it unstored
            raise NotStorable(key) from err
        try:
            _write(blob_path, bytes(exported.serialize()))
            _write(tree_path, pickle.dumps(out_tree))
        except OSError:
            pass  # a read-only cache: the program still runs, exported afresh next time
    # compiled ahead of time for these leaves (the persistent cache applies): called
    # through jit, the wrapper compiled a second time once the leaves came out of a
    # program (committed to the device)
    started = time.perf_counter()
    hits = _cache_hits()
    entry = (jit(exported.call).lower(*leaves).compile(), out_tree)
    # the compiler's free pages (~0.8 GB after the 200 x 200 seed scene's chunk)
    give_back_after(time.perf_counter() - started)
    if _cache_hits() == hits:
        # compiled here: one read back from JAX's cache does not serialize whole again
        # (loaded, it stopped on a kernel it could not find), so that one is not kept
        _write_executable(exe_path, entry[0])
    _loaded[key] = entry
    return entry


_HIT = "/jax/compilation_cache/cache_hits"
_hits_here = threading.local()  # JAX's cache hits in this thread (a prefetch compiles too)


@cache
def _listen_for_hits() -> None:
    def on_event(event, **kwargs):
        if event == _HIT:
            _hits_here.count = getattr(_hits_here, "count", 0) + 1

    jax.monitoring.register_event_listener(on_event)


def _cache_hits() -> int:
    """How many programs this thread has read from JAX's compilation cache so far."""
    _listen_for_hits()
    return getattr(_hits_here, "count", 0)


@cache
def machine_tag() -> str:
    """A short hash of what a compiled program is specific to beyond the key: the CPU
    (its model and instruction-set flags: XLA compiles for the host's), the backend's
    platform version and the ``XLA_FLAGS`` of the environment."""
    cpu = ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith(("model name", "flags")):
                cpu += line
                if line.startswith("flags"):
                    break
    except OSError:
        import platform

        cpu = f"{platform.machine()} {platform.processor()}"
    backend = jax.devices()[0].client
    parts = (cpu, backend.platform, backend.platform_version, os.environ.get("XLA_FLAGS", ""))
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()[:16]


def _write_executable(path: Path, compiled) -> None:
    """Keep the compiled wrapper itself (``{key}-{machine_tag}.xla``, zlib-compressed):
    a warm start then loads it without deserializing the exported program, lowering the
    wrapper and hashing it for JAX's cache.  Nothing where the program cannot be
    serialized or the disk refuses."""
    try:
        data, in_tree, out_tree = serialize_executable.serialize(compiled)
        _write(path, zlib.compress(pickle.dumps((data, in_tree, out_tree)), 1))
    except Exception:  # noqa: BLE001 - not serializable here: the exported program serves
        pass


@cache
def _lapack_ready() -> None:
    """Set up jaxlib's LAPACK kernels (their BLAS/LAPACK function pointers, which jaxlib
    fills in when it lowers a linear-algebra operation): a program loaded from its kept
    executable is not lowered in this process, and its LU (the dense solves) would call
    through a null pointer (a segmentation fault, seen on the modified-Newton chunk)."""
    try:
        from jax._src.lax.linalg import initialize_lapack

        initialize_lapack()
    except (ImportError, AttributeError):  # another jax: lowering one LU does the same
        jax.jit(jax.scipy.linalg.lu_factor).lower(jnp.eye(2))


def _read_executable(path: Path, tree_path: Path):
    """(compiled wrapper, output tree) from a kept executable, or None where it cannot be
    read or loaded: the file is then removed, and the exported program is compiled (and
    kept anew where that compile is not JAX's cache's)."""
    _lapack_ready()
    try:
        data, in_tree, out_tree = pickle.loads(zlib.decompress(path.read_bytes()))
        compiled = serialize_executable.deserialize_and_load(data, in_tree, out_tree)
        return compiled, pickle.loads(tree_path.read_bytes())
    except Exception:  # noqa: BLE001 - a damaged or foreign file: compile it again
        path.unlink(missing_ok=True)
        return None


def _keyed(name: str, static: str | None, args) -> tuple[str | None, list, object]:
    """(key, leaves, tree) of program ``name`` on ``args``.  The leaves get one signature
    whatever their weak types (a Python number passed in is weakly typed, the same value
    coming out of a program is not): the compiled wrapper is traced and compiled once,
    not once per weak-type pattern."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    leaves = [jnp.asarray(a, dtype=jnp.result_type(a)) for a in leaves]
    return program_key(name, static, jax.tree_util.tree_unflatten(tree, leaves)), leaves, tree


def prefetch(name: str, static: str | None, fn, *args) -> threading.Thread | None:
    """Start loading the stored program ``name`` for ``args`` (as :func:`call` would take
    them) in a background thread, where it is on disk and not loaded yet (a warm start):
    its loading (deserializing and linking the compiled program, which releases the
    interpreter) overlaps whatever the caller does next.  Returns the thread, which the
    caller joins before it calls the program, or None where there is nothing to load (or
    the process is past :data:`MAP_SHARE`: the thread would let programs go under the
    caller's work).  A failure in the thread is dropped: :func:`call` then prepares the
    program itself."""
    folder = store_dir()
    if folder is None or source_changed() or map_share() > MAP_SHARE:
        return None  # nothing stored, or a crowded process: the thread would make room
    key, leaves, tree = _keyed(name, static, args)
    if key is None or key in _loaded or key in _refused or not (folder / f"{key}.bin").is_file():
        return None

    def load():
        try:
            _prepared(key, fn, leaves, tree)
        except Exception:  # noqa: BLE001 - the call prepares it again and reports
            pass

    thread = threading.Thread(target=load, name=f"jaxform-load-{name}", daemon=True)
    thread.start()
    return thread


def call(name: str, static: str | None, fn, *args):
    """``fn(*args)``, through the stored program ``name`` where it can be (see the module
    docstring): ``fn`` must be a function of its arguments (pytrees of arrays) and of the
    static settings described by ``static`` alone."""
    if store_dir() is None or any(
        isinstance(a, jax.core.Tracer) for a in jax.tree_util.tree_leaves(args)
    ):
        return fn(*args)  # no store, or called inside a trace (the outer program's part)
    key, leaves, tree = _keyed(name, static, args)
    args = jax.tree_util.tree_unflatten(tree, leaves)
    if key is None or key in _refused:
        return fn(*args)
    try:
        wrapper, out_tree = _prepared(key, fn, leaves, tree)
    except NotStorable:
        _refused.add(key)  # traced as always, in this process from now on
        return fn(*args)
    return jax.tree_util.tree_unflatten(out_tree, wrapper(*leaves))
