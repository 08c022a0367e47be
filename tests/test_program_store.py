"""Stored (exported) programs: a warm start that skips tracing (jaxform.program_store).

References: the same run traced as always (store off) gives the same history; a program
loaded from the disk in a "new process" (the in-process table emptied) is not exported
again; the key changes with anything that shapes the program."""

from __future__ import annotations

import contextlib
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxform import program_store
from jaxform.cache import enable_compilation_cache
from jaxform.config import load_config
from jaxform.scenes import build_scene
from jaxform.simulation import simulate

SCENE = {
    "billet": {"diameter_mm": 5.0, "height_mm": 7.5},
    "mesh": {"nr": 3, "nz": 3, "element": "q1p0"},
    "die": {"speed_mm_s": 0.075, "reduction": 0.2},
    "friction": {"model": "coulomb", "mu": 0.3},
    "time": {"dt_s": 2.0},
    "output": {"fields": False, "plots": False},
}


def _force(sc):
    return simulate(sc).history["force_N"]


def test_a_stored_program_runs_like_the_traced_one(tmp_path, monkeypatch):
    """Store off, then exported, compiled and stored, then loaded from the disk with nothing
    in the process (from the kept executable: neither exported nor its exported program
    read), then again with the executable damaged (the file removed, the exported program
    compiled: JAX's cache serves it, and an executable read back from there is not kept,
    since it does not serialize whole): the four force histories agree to 1e-12 of the
    peak.  JAX's cache is a fresh directory here (the first compile is this test's)."""
    sc = build_scene(load_config(SCENE))
    monkeypatch.setenv(program_store.ENV_VAR, "off")
    plain = _force(sc)
    monkeypatch.delenv(program_store.ENV_VAR)
    monkeypatch.setattr(program_store, "store_dir", lambda: tmp_path / "exported")
    monkeypatch.setattr(program_store, "_loaded", {})
    with _jax_cache_in(tmp_path / "jax"):
        stored = _force(sc)
        _loaded_and_damaged(sc, tmp_path, monkeypatch, plain, stored)


@contextlib.contextmanager
def _jax_cache_in(path):
    """JAX's persistent compilation cache in ``path`` (fresh) for the block."""
    from jax.experimental.compilation_cache import compilation_cache as cc

    before = jax.config.jax_compilation_cache_dir
    enable_compilation_cache(path)
    try:
        yield
    finally:
        jax.config.update("jax_compilation_cache_dir", before)
        cc.reset_cache()


def _loaded_and_damaged(sc, tmp_path, monkeypatch, plain, stored):
    files = sorted(p.suffix for p in (tmp_path / "exported").iterdir())
    assert files == [".bin", ".tree", ".xla"]

    def no_export(*args):
        raise AssertionError("a stored program was exported again")

    def no_read(*args):
        raise AssertionError("the exported program was read where its executable is kept")

    read_exported = program_store.export.deserialize
    monkeypatch.setattr(program_store, "_loaded", {})  # as in a new process
    monkeypatch.setattr(program_store, "_export", no_export)
    monkeypatch.setattr(program_store.export, "deserialize", no_read)
    loaded = _force(sc)
    (kept,) = (tmp_path / "exported").glob("*.xla")
    kept.write_bytes(b"not an executable")
    monkeypatch.setattr(program_store.export, "deserialize", read_exported)
    monkeypatch.setattr(program_store, "_loaded", {})
    again = _force(sc)
    assert not kept.exists()  # removed, and not kept from JAX's cache
    peak = np.max(plain)
    assert peak > 10.0 and len(plain) >= 3
    for run in (stored, loaded, again):
        assert np.max(np.abs(run - plain)) <= 1e-12 * peak


def test_the_key_follows_what_shapes_the_program(monkeypatch):
    args = (jnp.zeros(3), {"a": jnp.ones((2, 2))})

    def key(name="f", static="Settings(n=1)", a=args):
        return program_store.program_key(name, static, a)

    assert key() == key()
    assert key() != key(static="Settings(n=2)")
    assert key() != key(name="g")
    assert key() != key(a=(jnp.zeros(4), args[1]))
    assert key() != key(a=(jnp.zeros(3, int), args[1]))
    assert key() != key(a=(jnp.zeros(3), {"b": args[1]["a"]}))
    # no stable description of the settings: nothing is stored
    assert key(static="<object at 0x7f00deadbeef>") is None
    # the source of jaxform is part of the key
    before = key()
    monkeypatch.setattr(program_store, "code_fingerprint", lambda: "changed")
    assert key() != before


def test_a_program_that_cannot_be_exported_runs_traced(tmp_path, monkeypatch):
    """An export that fails (here: refused) leaves the call to the traced function."""
    monkeypatch.setattr(program_store, "store_dir", lambda: tmp_path)
    monkeypatch.setattr(program_store, "_loaded", {})
    monkeypatch.setattr(program_store, "_refused", set())

    def refuse(*args):
        raise ValueError("not exportable")

    monkeypatch.setattr(program_store, "_export", refuse)
    out = program_store.call("double", "Double()", lambda x: 2.0 * x, jnp.arange(3.0))
    np.testing.assert_array_equal(np.asarray(out), [0.0, 2.0, 4.0])
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ZeroDivisionError):  # an error of the function itself still raises
        program_store.call("bad", "Bad()", lambda x: 1 // 0, jnp.arange(3.0))


def _maps() -> int:
    with open("/proc/self/maps", "rb") as f:
        return sum(1 for _ in f)


def test_a_crowded_process_lets_its_programs_go(tmp_path, monkeypatch):
    """Reference: Linux stops a process at vm.max_map_count memory maps (65530 by
    default) and each compiled CPU program holds some until it is let go (the default
    suite's workers aborted in XLA after about 20 minutes of compiling).  Twenty stored
    programs add at least two maps each; under the share nothing is let go; past it (the
    share set to 0) the next new program first lets the twenty go, and their maps with
    them."""
    if program_store.map_share() == 0.0:
        pytest.skip("no memory-map limit to read on this system (/proc)")
    monkeypatch.setattr(program_store, "store_dir", lambda: tmp_path)
    monkeypatch.setattr(program_store, "_loaded", {})
    monkeypatch.setattr(program_store, "_stored_floor", 0.0)
    x = jnp.arange(3.0)
    before = _maps()
    for k in range(20):
        program_store.call(f"scale{k}", f"Scale(k={k})", lambda x, k=k: k * x + jnp.sin(x), x)
    grown = _maps()
    assert len(program_store._loaded) == 20
    assert grown >= before + 2 * 20
    assert not program_store.release_if_crowded(share=1.0)
    assert len(program_store._loaded) == 20
    monkeypatch.setattr(program_store, "MAP_SHARE", 0.0)
    monkeypatch.setattr(program_store, "STORED_STEP", 0.0)
    monkeypatch.setattr(program_store, "_room_checked_at", -float("inf"))  # interval over
    out = program_store.call("scale20", "Scale(k=20)", lambda x: 20.0 * x + jnp.sin(x), x)
    np.testing.assert_allclose(np.asarray(out), 20.0 * np.arange(3.0) + np.sin(np.arange(3.0)))
    assert len(program_store._loaded) == 1
    assert _maps() <= grown - 2 * 19


def test_letting_the_compiled_programs_go_keeps_their_traces():
    """Reference: ten compiled programs (and a gradient through one of them, a program
    holding a traced inner one) hold at least two memory maps each; after
    release_compiled the process holds fewer than one map more than before them, and
    calling them again compiles them but traces nothing (each trace runs the Python
    body once: the count of traces does not grow)."""
    if program_store.map_share() == 0.0:
        pytest.skip("no memory-map limit to read on this system (/proc)")
    traced = []

    @jax.jit
    def f(x, k):
        traced.append(1)
        return jnp.sin(x) * k + jnp.cumsum(x)

    @jax.jit
    def g(x):
        return jax.grad(lambda y: f(y, 3.0).sum())(x)

    xs = [jnp.arange(float(n)) for n in range(3, 13)]
    before = _maps()
    for x in xs:
        f(x, 2.0).block_until_ready()
    g(xs[0]).block_until_ready()
    n_traces = len(traced)
    assert _maps() >= before + 2 * 10
    assert program_store.release_compiled()
    assert _maps() < before + 10
    for x in xs:
        np.testing.assert_allclose(np.asarray(f(x, 2.0)), np.sin(x) * 2.0 + np.cumsum(x))
    np.testing.assert_allclose(np.asarray(g(xs[0])), 3.0 * np.cos(xs[0]) + np.arange(3.0, 0, -1))
    assert len(traced) == n_traces


@pytest.mark.parametrize(
    "share, stored, floor, after, expected",
    [(0.4, True, 0.0, 0.4, None), (0.7, True, 0.0, 0.7, "stored"),
     (0.7, False, 0.0, 0.7, None), (0.7, True, 0.65, 0.7, None),
     (0.76, True, 0.65, 0.76, "stored"), (0.9, True, 0.0, 0.9, "all"),
     (0.9, False, 0.0, 0.9, "all"), (0.9, True, 0.85, 0.9, "all"),
     (0.9, True, 0.0, 0.4, "compiled"), (0.9, False, 0.0, 0.6, "compiled")],
)  # fmt: skip
def test_making_room_lets_the_stored_programs_go_first(monkeypatch, share, stored, floor,
                                                       after, expected):  # fmt: skip
    """Reference: the policy of make_room, before a stored program, a replay's mesh or
    reverse pass and a design's evaluation (a gradient replay's programs are needed again
    at its next evaluation; the shipped two-stage disk's alone hold ~75 % of the map
    limit, and letting them go made every gradient trace again, 134-200 s against 3 s
    warm).  At or below MAP_SHARE nothing goes; between MAP_SHARE and CLEAR_SHARE only
    the stored programs (JAX's caches stay), and only once the share has grown by
    STORED_STEP (0.1) since they last went (``floor``: a forward run beside a design's
    gradient programs does not read its programs back at each new one); past CLEAR_SHARE
    JAX's compiled executables (their traces stay; ``after``: the share then), and
    everything where that does not bring it under CLEAR_SHARE.  The share is read again
    after the stored programs went (here it does not fall)."""
    calls = []
    now = [share]

    def compiled():
        calls.append("compiled")
        now[0] = after
        return True

    monkeypatch.setattr(program_store, "_room_checked_at", -float("inf"))
    monkeypatch.setattr(program_store, "_last_share", None)
    monkeypatch.setattr(program_store, "_largest_rise", 0.0)
    monkeypatch.setattr(program_store, "_stored_floor", floor)
    monkeypatch.setattr(program_store, "MAP_SHARE", 0.5)
    monkeypatch.setattr(program_store, "CLEAR_SHARE", 0.85)
    monkeypatch.setattr(program_store, "map_share", lambda: now[0])
    monkeypatch.setattr(program_store, "_loaded", {"k": None} if stored else {})
    monkeypatch.setattr(program_store, "release_programs", lambda: calls.append("all"))
    monkeypatch.setattr(program_store, "release_compiled", compiled)
    assert program_store.make_room() == expected
    assert calls == {"all": ["compiled", "all"], "compiled": ["compiled"]}.get(expected, [])
    assert bool(program_store._loaded) == (stored and expected is None)
    if expected == "stored":
        assert program_store._stored_floor == share


def test_making_room_keeps_room_for_the_largest_rise_seen(monkeypatch):
    """Reference: HEADROOM_SHARE (0.95).  Readings of 0.30 and 0.55 (a rise of 0.25; no
    stored programs) let nothing go; at 0.75, below CLEAR_SHARE (0.85) but within the
    largest rise of 0.95, JAX's compiled executables go (to 0.20); the readings after that
    (0.45, a rise of 0.25 again) let nothing go, and a larger rise (to 0.72, 0.27) counts
    from then on."""
    calls, now = [], [0.0]

    def compiled():
        calls.append("compiled")
        now[0] = 0.2
        return True

    monkeypatch.setattr(program_store, "_last_share", None)
    monkeypatch.setattr(program_store, "_largest_rise", 0.0)
    monkeypatch.setattr(program_store, "_stored_floor", 0.0)
    monkeypatch.setattr(program_store, "MAP_SHARE", 0.5)
    monkeypatch.setattr(program_store, "CLEAR_SHARE", 0.85)
    monkeypatch.setattr(program_store, "map_share", lambda: now[0])
    monkeypatch.setattr(program_store, "_loaded", {})
    monkeypatch.setattr(program_store, "release_programs", lambda: calls.append("all"))
    monkeypatch.setattr(program_store, "release_compiled", compiled)
    done = []
    for share in (0.30, 0.55, 0.75, 0.45, 0.72):
        monkeypatch.setattr(program_store, "_room_checked_at", -float("inf"))
        now[0] = share
        done.append(program_store.make_room())
    assert done == [None, None, "compiled", None, "compiled"]
    assert calls == ["compiled", "compiled"]
    assert program_store._largest_rise == pytest.approx(0.27)


def test_a_process_that_cannot_make_room_for_the_largest_rise_is_warned_once(monkeypatch):
    """Reference: the kernel's limit.  Readings of 0.30 and 0.70 (a rise of 0.40) with
    programs that do not let go (the share stays): make_room lets everything go, the
    share plus the rise still passes the whole limit, and MapLimitWarning names the
    remedy (vm.max_map_count), once a process."""
    now = [0.3]
    monkeypatch.setattr(program_store, "_last_share", None)
    monkeypatch.setattr(program_store, "_largest_rise", 0.0)
    monkeypatch.setattr(program_store, "_warned_limit", False)
    monkeypatch.setattr(program_store, "map_share", lambda: now[0])
    monkeypatch.setattr(program_store, "_loaded", {})
    monkeypatch.setattr(program_store, "release_programs", lambda: None)
    monkeypatch.setattr(program_store, "release_compiled", lambda: True)
    monkeypatch.setattr(program_store, "_room_checked_at", -float("inf"))
    assert program_store.make_room() is None
    now[0] = 0.7
    monkeypatch.setattr(program_store, "_room_checked_at", -float("inf"))
    with pytest.warns(program_store.MapLimitWarning, match="vm.max_map_count"):
        assert program_store.make_room() == "all"
    monkeypatch.setattr(program_store, "_room_checked_at", -float("inf"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        program_store.make_room()  # once a process


def test_making_room_reads_the_map_table_at_most_once_an_interval(monkeypatch):
    """Reference: ROOM_CHECK_INTERVAL_S.  Reading /proc/self/maps costs 2-10 ms in a
    process holding hundreds of programs (a test worker), which was 80 % of a CMA-ES
    run of 2600 closed-form evaluations there (18.6 s against 3.5 s alone): make_room
    reads it once, not again within the interval, and again after it."""
    reads, clock = [], [100.0]
    monkeypatch.setattr(program_store, "_room_checked_at", -float("inf"))
    monkeypatch.setattr(program_store, "map_share", lambda: reads.append(1) or 0.1)
    monkeypatch.setattr(program_store, "_clock", lambda: clock[0])
    for _ in range(50):
        assert program_store.make_room() is None
    assert len(reads) == 1
    clock[0] += 0.9 * program_store.ROOM_CHECK_INTERVAL_S
    program_store.make_room()
    assert len(reads) == 1
    clock[0] += 0.2 * program_store.ROOM_CHECK_INTERVAL_S
    program_store.make_room()
    assert len(reads) == 2


def test_letting_the_stored_programs_go_frees_their_maps(tmp_path, monkeypatch):
    """Reference: /proc/self/maps.  Ten stored programs add at least two maps each;
    release_stored_programs lets them go (the table empty, at least two maps each fewer)
    and leaves a jitted program's compiled executable in JAX's cache (called again it
    is not traced again)."""
    if program_store.map_share() == 0.0:
        pytest.skip("no memory-map limit to read on this system (/proc)")
    import jax

    monkeypatch.setattr(program_store, "store_dir", lambda: tmp_path)
    monkeypatch.setattr(program_store, "_loaded", {})
    monkeypatch.setattr(program_store, "MAP_SHARE", 1.0)  # the ten stay until let go here
    monkeypatch.setattr(program_store, "CLEAR_SHARE", 1.0)
    traces = []

    @jax.jit
    def kept(x):
        traces.append(1)
        return jnp.cos(x) * 3.0

    x = jnp.arange(3.0)
    kept(x)
    before = _maps()
    for k in range(10):
        program_store.call(f"shift{k}", f"Shift(k={k})", lambda x, k=k: x + k * jnp.cos(x), x)
    grown = _maps()
    assert grown >= before + 2 * 10
    assert program_store.release_stored_programs()
    assert not program_store._loaded
    assert _maps() <= grown - 2 * 10
    assert not program_store.release_stored_programs()  # nothing left to let go
    kept(x)
    assert len(traces) == 1


def test_a_source_edited_under_the_process_turns_the_store_off(tmp_path, monkeypatch):
    """A jaxform file that changes on disk after the process read the source: programs
    are neither loaded nor stored from then on (a program traced from the edited code must
    not sit under the old code's key); the call still runs, traced."""
    src = tmp_path / "pkg"
    src.mkdir()
    (src / "a.py").write_text("x = 1\n")
    monkeypatch.setattr(program_store, "_ROOT", src)
    program_store._source_at_start.cache_clear()
    monkeypatch.setattr(program_store, "store_dir", lambda: tmp_path / "exported")
    monkeypatch.setattr(program_store, "_loaded", {})
    try:
        before = program_store.code_fingerprint()
        assert not program_store.source_changed()
        (src / "a.py").write_text("x = 22\n")  # another size: a change whatever the clock
        assert program_store.source_changed()
        assert program_store.code_fingerprint() == before  # the key stays the old source's
        out = program_store.call("f", "S()", lambda a: a * 2.0, jnp.arange(3.0))
        np.testing.assert_array_equal(out, [0.0, 2.0, 4.0])
        assert not (tmp_path / "exported").exists()  # nothing stored
    finally:
        program_store._source_at_start.cache_clear()


def test_a_prefetched_program_is_loaded_beside_the_callers_work(tmp_path, monkeypatch):
    """program_store.prefetch: nothing to load before the program is stored, nor for a
    description with an object address, nor in a crowded process; once stored, in a "new
    process" a thread loads it, and the call after the join reads nothing from the disk
    and returns what the function returns (to the last bit)."""
    import jax

    monkeypatch.setattr(program_store, "store_dir", lambda: tmp_path)
    monkeypatch.setattr(program_store, "_loaded", {})
    fn = jax.jit(lambda a, b: (jnp.sin(a) * b, jnp.sum(a)))
    args = (jnp.arange(4.0), jnp.asarray(2.0))
    assert program_store.prefetch("prefetched", "s", fn, *args) is None  # not stored yet
    first = program_store.call("prefetched", "s", fn, *args)
    assert program_store.prefetch("prefetched", "s", fn, *args) is None  # loaded already
    assert program_store.prefetch("prefetched", "<f at 0x7f00>", fn, *args) is None
    monkeypatch.setattr(program_store, "_loaded", {})  # as in a new process
    monkeypatch.setattr(program_store, "MAP_SHARE", -1.0)  # crowded: no thread
    assert program_store.prefetch("prefetched", "s", fn, *args) is None
    monkeypatch.setattr(program_store, "MAP_SHARE", 0.5)
    thread = program_store.prefetch("prefetched", "s", fn, *args)
    assert thread is not None
    thread.join()
    assert len(program_store._loaded) == 1

    def no_read(*a, **k):
        raise AssertionError("the prefetched program was read again")

    monkeypatch.setattr(program_store.export, "deserialize", no_read)
    again = program_store.call("prefetched", "s", fn, *args)
    for a, b in zip(jax.tree_util.tree_leaves(first), jax.tree_util.tree_leaves(again)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_the_guessed_schedule_is_the_forward_runs_without_cutbacks():
    """build_problem loads the gradient program for the steps of a run at time.dt_s
    throughout (Scene.step_targets) while the forward run fixes the schedule: on this
    scene (no cutback) the guess is the run's schedule; 7.5 mm x 0.2 / 0.075 mm/s = 20 s
    at 2 s is 10 steps, and with dt 3 s the last is shorter (7 steps, the last of 2 s)."""
    sc = build_scene(load_config(SCENE))
    hist = simulate(sc).history
    assert hist["cutbacks"].max() == 0
    np.testing.assert_allclose(sc.step_targets(), hist["time_s"][1:], rtol=0, atol=1e-12)
    assert len(sc.step_targets()) == 10
    targets = build_scene(load_config(SCENE, ["time.dt_s=3.0"])).step_targets()
    assert len(targets) == 7 and targets[-1] - targets[-2] == pytest.approx(2.0)
