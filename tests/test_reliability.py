"""The pieces that keep run directories whole under concurrency, full disks, signals and hostile values.

Each piece is checked against the operating system itself (real processes holding real locks,
real signals during a call into C, a real full file system, real read-only and immutable
directories where this process may make them) and against independent computations (NumPy's
float32 limits, ``json`` line by line, the bytes of arrays actually allocated).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import pathlib
import shutil
import signal
import struct
import subprocess
import sys
import textwrap
import threading
import time

import jax
import numpy as np
import pytest

from nmrl import learners, options
from nmrl.runs import bounds, io_errors, jsonl, lock, memory, parser, signals

PY = sys.executable


def _spawn(code: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen([PY, "-c", textwrap.dedent(code), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def _wait_line(p: subprocess.Popen, want: str, timeout: float = 60) -> str:
    t0 = time.time()
    while time.time() - t0 < timeout:
        line = p.stdout.readline()
        if want in line:
            return line
        if not line and p.poll() is not None:
            raise AssertionError(f"process ended ({p.returncode}): {p.stderr.read()[-2000:]}")
    raise AssertionError(f"no {want!r} within {timeout} s")


# ----------------------------------------------------------------------------- one writer per directory

_HOLDER = """
import sys, time
from nmrl.runs import lock
h = lock.hold(sys.argv[1])
print("held", flush=True)
time.sleep(600)
"""


def test_a_second_writer_is_refused_naming_the_holder_and_the_os_releases_a_killed_holder(tmp_path):
    d = tmp_path / "run"
    p = _spawn(_HOLDER, str(d))
    try:
        _wait_line(p, "held")
        assert lock.holder_of(d)["pid"] == p.pid
        with pytest.raises(lock.Locked) as e:
            lock.hold(d)
        msg = str(e.value)
        assert "\n" not in msg and f"pid {p.pid}" in msg and "started " in msg and str(d) in msg
        assert "-c" in msg  # the holder's command line
    finally:
        p.kill()
        p.wait()
    assert lock.holder_of(d) is None  # SIGKILL: the kernel dropped the lock with the process
    with lock.hold(d):
        assert lock.held(d) and lock.holder_of(d)["pid"] == os.getpid()
    assert not lock.held(d) and not (d / lock.LOCK_FILE).exists()


def test_one_process_counts_its_holds_and_a_refusal_changes_nothing(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    (d / "config.json").write_text("{}")
    a = lock.hold(d)
    b = lock.hold(d)  # a sweep's nested hold of the same directory
    a.release()
    assert lock.held(d)
    p = _spawn("import sys\nfrom nmrl.runs import lock\ntry:\n    lock.hold(sys.argv[1])\n"
               "except lock.Locked as e:\n    print('refused', e)\n", str(d))
    out, err = p.communicate(timeout=60)
    assert out.startswith("refused") and f"pid {os.getpid()}" in out, err
    b.release()
    assert not lock.held(d) and sorted(x.name for x in d.iterdir()) == ["config.json"]


def test_a_directory_made_for_the_lock_is_removed_when_left_empty(tmp_path):
    d = tmp_path / "new" / "run"
    lock.hold(d).release(remove_if_empty=True)
    assert not d.exists()
    h = lock.hold(d)
    (d / "config.json").write_text("{}")
    h.release(remove_if_empty=True)
    assert sorted(x.name for x in d.iterdir()) == ["config.json"]


_RACER = """
import sys, time
from nmrl.runs import lock
start = float(sys.argv[2])
while time.time() < start:
    pass
try:
    h = lock.hold(sys.argv[1])
except lock.Locked:
    print("refused", flush=True)
else:
    print("won", flush=True)
    time.sleep(1.5)
    h.release()
"""


def test_writers_started_at_the_same_moment_get_exactly_one_lock(tmp_path):
    d = tmp_path / "run"
    d.mkdir()
    start = time.time() + 3.0
    ps = [_spawn(_RACER, str(d), repr(start)) for _ in range(6)]
    outs = [p.communicate(timeout=120)[0].strip() for p in ps]
    assert sorted(outs) == ["refused"] * 5 + ["won"], outs


# ----------------------------------------------------------------------------- disk and file system failures


def test_find_names_the_cause_through_wrappers_and_messages():
    e = OSError(errno.ENOSPC, "No space left on device", "/x/checkpoints/300")
    try:
        try:
            raise e
        except OSError as inner:
            raise RuntimeError("saving failed") from inner
    except RuntimeError as outer:
        f = io_errors.find(outer)
    assert f == io_errors.Failure(errno.ENOSPC, "/x/checkpoints/300", io_errors.CAUSES[errno.ENOSPC])
    # orbax/tensorstore keep only the text
    f = io_errors.find(ValueError("Error writing '/r/c/1/state/d/ab': [errno 30] Read-only file system"))
    assert (f.errno, f.path) == (errno.EROFS, "/r/c/1/state/d/ab")
    assert io_errors.find(ValueError("shapes differ")) is None
    group = ExceptionGroup("tasks", [ValueError("x"), PermissionError(errno.EACCES, "Permission denied", "/p")])
    assert io_errors.find(group).errno == errno.EACCES


def _can_mount() -> bool:
    return sys.platform.startswith("linux") and os.geteuid() == 0 and shutil.which("mount") is not None


@pytest.fixture
def small_fs(tmp_path):
    d = tmp_path / "fs"
    d.mkdir()
    if not _can_mount() or subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(d)],
                                          capture_output=True).returncode != 0:
        pytest.skip("needs root with CAP_SYS_ADMIN to mount a small tmpfs")
    yield d
    subprocess.run(["umount", "-l", str(d)], capture_output=True)


def test_a_full_disk_is_named_with_the_path(small_fs):
    target = small_fs / "big.bin"
    with pytest.raises(OSError) as e:
        target.write_bytes(b"\0" * (4 << 20))
    f = io_errors.find(e.value, target)
    assert f.errno == errno.ENOSPC and f.path == str(target)
    assert io_errors.IOFailure(f).args[0] == f"cannot write {target}: the disk is full (no space left on device)"


def test_read_only_and_immutable_directories_are_found_by_writing(small_fs, tmp_path):
    io_errors.check_writable(small_fs / "new" / "dir")  # writable; the directories made for the check are gone
    assert list(small_fs.iterdir()) == []
    assert subprocess.run(["mount", "-o", "remount,ro", str(small_fs)], capture_output=True).returncode == 0
    with pytest.raises(io_errors.IOFailure) as e:
        io_errors.check_writable(small_fs)
    assert e.value.failure.errno == errno.EROFS and "read-only" in str(e.value) and str(small_fs) in str(e.value)
    imm = tmp_path / "imm"
    imm.mkdir()
    if subprocess.run(["chattr", "+i", str(imm)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i is not available on this file system")
    try:
        with pytest.raises(io_errors.IOFailure) as e:
            io_errors.check_writable(imm)
        assert e.value.failure.errno == errno.EPERM and "immutable (chattr +i" in str(e.value)
        assert io_errors.immutable(imm) == "immutable"
    finally:
        subprocess.run(["chattr", "-i", str(imm)], capture_output=True)
    assert io_errors.immutable(imm) is None


LATE_TRACEBACK = """
    import sys, threading, time
    from nmrl.runs import io_errors

    io_errors.mute_after_report = sys.argv[1] == "mute"

    def late():  # a library's worker thread that logs the same failure once the command has spoken
        time.sleep(0.3)
        try:
            raise OSError(28, "No space left on device")
        except OSError:
            import traceback
            traceback.print_exc()

    t = threading.Thread(target=late)
    t.start()
    io_errors.report("nmrl: error: cannot write /r/checkpoints/200: the disk is full")
    sys.exit(5)
"""


@pytest.mark.parametrize("mute", ["mute", "keep"])
def test_a_disk_failure_line_is_the_last_thing_on_stderr_of_the_command(mute):
    p = _spawn(LATE_TRACEBACK, mute)
    out, err = p.communicate(timeout=60)
    lines = [x for x in err.splitlines() if x.strip()]
    assert p.returncode == 5 and lines[0] == "nmrl: error: cannot write /r/checkpoints/200: the disk is full"
    if mute == "mute":  # the process's entry point: the late traceback does not reach stderr
        assert lines == lines[:1], err
    else:  # called in-process (tests, other programs): their stderr is left alone
        assert lines[1] == "Traceback (most recent call last):" and "No space left on device" in lines[-1]


class _OrbaxThread(threading.Thread):
    """Stands for one of orbax's save threads (the quiet context recognises them by their module)."""


_OrbaxThread.__module__ = "orbax.checkpoint._src.futures.future"


@pytest.fixture
def absl_records(monkeypatch):
    """The records the absl logger passes on while a test runs (its handler and the quiet context's
    filters removed afterwards)."""
    from nmrl.runs import checkpoint_steps

    seen: list[logging.LogRecord] = []

    class Keep(logging.Handler):
        def emit(self, record):
            seen.append(record)

    absl = logging.getLogger("absl")
    h = Keep(level=logging.DEBUG)
    absl.addHandler(h)
    yield seen
    absl.removeHandler(h)
    for lg in map(logging.getLogger, ("absl", "orbax", "asyncio")):
        for f in [f for f in lg.filters if isinstance(f, checkpoint_steps._FromThreads)]:
            lg.removeFilter(f)


def test_what_a_failed_saves_straggling_thread_logs_later_stays_off_the_log(monkeypatch, absl_records):
    from nmrl.runs import checkpoint_steps

    monkeypatch.setattr(checkpoint_steps, "_SETTLE_S", 0.05)  # the thread outlives the wait, as under load
    absl = logging.getLogger("absl")
    go = threading.Event()
    late = _OrbaxThread(target=lambda: (go.wait(10), absl.error("_SignalingThread.run() raised an exception")))
    try:
        with pytest.raises(OSError):
            with checkpoint_steps._quiet_absl():
                late.start()
                raise OSError(28, "No space left on device")
        assert late.is_alive() and absl.level != logging.CRITICAL  # the loggers speak again
    finally:
        go.set()
        late.join(10)
    absl.error("the next failure")  # another thread's record is still logged
    assert [r.getMessage() for r in absl_records] == ["the next failure"]


class _FailedOrbaxThread(_OrbaxThread):
    """Like orbax's _SignalingThread: join() raises the failure the thread ended with."""

    def join(self, timeout=None):
        super().join(timeout)
        raise OSError(28, "No space left on device")


_FailedOrbaxThread.__module__ = _OrbaxThread.__module__


def test_a_thread_that_raises_from_join_does_not_stop_the_wait_for_the_others(monkeypatch, absl_records):
    from nmrl.runs import checkpoint_steps

    monkeypatch.setattr(checkpoint_steps, "_SETTLE_S", 30.0)
    absl = logging.getLogger("absl")
    failed = _FailedOrbaxThread(target=lambda: time.sleep(0.2))  # enumerated first: waited for first
    late = _OrbaxThread(target=lambda: (time.sleep(0.5), absl.error("_SignalingThread.run() raised an exception")))
    try:
        with pytest.raises(OSError):
            with checkpoint_steps._quiet_absl():
                failed.start()
                late.start()
                raise OSError(28, "No space left on device")
        assert not late.is_alive()  # waited for while the loggers were quiet
    finally:
        threading.Thread.join(late, 10)
    assert absl_records == []


def test_partial_saves_are_removed_and_finished_steps_kept(tmp_path):
    c = tmp_path / "checkpoints"
    (c / "200" / "state").mkdir(parents=True)
    (c / "300.orbax-checkpoint-tmp-1733" / "state").mkdir(parents=True)
    gone = io_errors.remove_partial_saves(c)
    assert [g.name for g in gone] == ["300.orbax-checkpoint-tmp-1733"]
    assert [x.name for x in c.iterdir()] == ["200"]


def test_a_partial_save_still_being_written_is_removed_once_its_writer_stops(tmp_path):
    import threading

    part = tmp_path / "checkpoints" / "300.orbax-checkpoint-tmp" / "state"
    part.mkdir(parents=True)
    stop = time.monotonic() + 0.5

    def writer():  # a library thread of the failed save, still adding files for half a second
        i = 0
        while time.monotonic() < stop:
            with contextlib.suppress(OSError):  # once the directory is gone, its writes fail
                (part / f"d{i}").write_bytes(b"x" * 4096)
            i += 1

    t = threading.Thread(target=writer)
    t.start()
    time.sleep(0.05)
    io_errors.remove_partial_saves(tmp_path / "checkpoints")
    t.join()
    assert list((tmp_path / "checkpoints").iterdir()) == []


def test_a_partial_save_its_writer_creates_again_is_removed_again(tmp_path):
    import threading

    part = tmp_path / "checkpoints" / "200.orbax-checkpoint-tmp" / "state"
    part.mkdir(parents=True)
    removed, created = threading.Event(), threading.Event()

    def writer():  # tensorstore's file store: it creates the parents of what it writes, after the removal
        while part.exists():
            time.sleep(0.005)
        removed.set()
        time.sleep(0.2)
        part.parent.mkdir(exist_ok=True)
        created.set()
        try:
            part.mkdir(exist_ok=True)
            (part / "d0").write_bytes(b"x" * 4096)
        except FileNotFoundError:  # removed again under the write: the write fails, as tensorstore's does
            pass

    t = threading.Thread(target=writer)
    t.start()
    io_errors.remove_partial_saves(tmp_path / "checkpoints")
    t.join()
    assert removed.is_set() and created.is_set() and list((tmp_path / "checkpoints").iterdir()) == []


# ----------------------------------------------------------------------------- JSON lines after a crash


def _rows(n: int) -> list[dict]:
    return [{"chunk": i + 1, "step": 100 * (i + 1), "avg_reward": -0.5 + 0.01 * i} for i in range(n)]


def test_an_unfinished_last_line_is_dropped_with_one_warning(tmp_path):
    p = tmp_path / "metrics.jsonl"
    full = "".join(json.dumps(r) + "\n" for r in _rows(4))
    for cut in (1, 10, len(json.dumps(_rows(4)[-1]))):  # a crash anywhere inside the last append
        p.write_text(full[:-1 - cut] if cut < len(json.dumps(_rows(4)[-1])) else full[: full.rindex("{")] + "{")
        warnings: list[str] = []
        rows = jsonl.read(p, warnings.append)
        assert rows == [json.loads(x) for x in full.splitlines()[:3]]
        assert len(warnings) == 1 and str(p) in warnings[0] and "line 4" in warnings[0]
        assert jsonl.has_partial_tail(p)
        assert jsonl.complete_tail(p) and p.read_text() == "".join(full.splitlines(True)[:3])
    p.write_text(full[:-1])  # the whole object, only the newline missing: a complete row
    assert jsonl.read(p) == _rows(4) and not jsonl.has_partial_tail(p)
    assert jsonl.complete_tail(p) and p.read_text() == full


@pytest.mark.parametrize("text, line", [
    ('{"step": 100}\n{"step": 2\n{"step": 300}\n', 2),  # a damaged middle line
    ('{"step": 100}\n{"step": 2\n', 2),  # a last line that ends with its newline and does not parse
    ('{"step": 100}\n[1, 2]\n', 2),  # not an object
])
def test_other_damage_is_one_line_naming_the_file_and_line(tmp_path, text, line):
    p = tmp_path / "metrics.jsonl"
    p.write_text(text)
    with pytest.raises(jsonl.Corrupt) as e:
        jsonl.read(p)
    assert "\n" not in str(e.value) and f"{p}: line {line} " in str(e.value)


# ----------------------------------------------------------------------------- bounds of every number


def test_every_learners_defaults_are_within_bounds():
    for name in learners.names():
        cfg = learners.get(name).config()
        bounds.check(cfg)


@pytest.mark.parametrize("field, value, needle", [
    ("sigma", 1e300, "sigma=1e+300 is invalid: must be a finite number in float32"),
    ("beta_theta", 1e300, "beta_theta=1e+300 is invalid: must be a finite number in float32"),
    ("control_dt", 1e300, "control_dt=1e+300 is invalid: must be a finite number in float32"),
    ("control_dt", 2.0, "control_dt=2.0 is invalid: must be in (0, 1]"),
    ("sigma", 11.0, "sigma=11.0 is invalid: must be in (0, 10]"),
    ("beta_v", 2.0, "beta_v=2.0 is invalid: must be in [0, 1]"),
    ("stop_prob", 1.5, "stop_prob=1.5 is invalid: must be in [0, 1]"),
    ("gamma", 1e-40, "gamma=1e-40 is invalid: below float32's smallest normal number"),
    ("max_param_norm", float("inf"), "max_param_norm=inf is invalid: must be a finite number"),
    ("num_envs", 2**40, "num_envs=1099511627776 is invalid: must fit in 32 bits"),
    ("steps", 2**31, "steps=2147483648 is invalid: must fit in 32 bits"),
])
def test_out_of_bounds_values_are_named_in_one_line(field, value, needle):
    cfg = options.replace(learners.get("ac").config(), **{field: value})
    with pytest.raises(ValueError) as e:
        bounds.check(cfg)
    assert str(e.value).startswith(needle) and "\n" not in str(e.value)


def test_the_float32_bound_is_the_c_cast():
    """The reference: C's cast to float (``struct``'s packing): what rounds beyond float32's range is refused."""
    f32 = np.finfo(np.float32)
    half_ulp = (float(f32.max) - float(np.nextafter(f32.max, np.float32(0)))) / 2
    for x in (float(f32.max), float(f32.max) + half_ulp / 2, float(f32.max) + 2 * half_ulp, 1e38, 3.5e38,
              -3.5e38, float(f32.tiny), float(f32.tiny) / 2, 1e-45, 0.0, -1.0):
        try:
            y = struct.unpack("f", struct.pack("f", x))[0]
            ok = np.isfinite(y) and (x == 0 or abs(y) >= float(f32.tiny))
        except OverflowError:
            ok = False
        try:
            bounds.check_value("x", x)
            passed = True
        except ValueError:
            passed = False
        assert passed == ok, x


# ----------------------------------------------------------------------------- one-line parser errors


def test_parser_errors_are_one_line_without_the_usage():
    p = parser.OneLineParser(prog="nmrl")
    sub = p.add_subparsers(dest="cmd")
    t = sub.add_parser("train")
    t.add_argument("--num-envs", type=int)
    t.add_argument("--sigma", type=float)
    t.add_argument("--seed", type=parser.integer)
    cases = {("--num-envs", "1.5"): "nmrl train: error: --num-envs='1.5' is invalid: must be an integer",
             ("--sigma", "x"): "nmrl train: error: --sigma='x' is invalid: must be a number",
             ("--seed", "1e300"): "nmrl train: error: --seed='1e300' is invalid: must be an integer",
             ("--trials", "-5"): "nmrl: error: unknown option(s) --trials -5"}
    for argv, want in cases.items():
        r = subprocess.run([PY, "-c", "import sys\nfrom nmrl.runs import parser\n"
                            "p = parser.OneLineParser(prog='nmrl'); s = p.add_subparsers(dest='cmd')\n"
                            "t = s.add_parser('train'); t.add_argument('--num-envs', type=int)\n"
                            "t.add_argument('--sigma', type=float); t.add_argument('--seed', type=parser.integer)\n"
                            "p.parse_args(sys.argv[1:])", "train", *argv], capture_output=True, text=True)
        assert r.returncode == 2 and r.stderr.splitlines() == [f"{want} (see {want.split(':')[0]} --help)"], r.stderr
    assert parser.integer("+12") == 12 and p.parse_args(["train", "--seed", "7"]).seed == 7


# ----------------------------------------------------------------------------- signals while in C


_IN_C = """
import ctypes, sys, time
from nmrl.runs.signals import Guard, Interrupted
g = Guard().install()
g.at("compiling")
print("ready", flush=True)
t0 = time.time()
libc = ctypes.CDLL(None)
while time.time() - t0 < 4:   # the main thread in C, as in an XLA compile (sleep restarts after EINTR)
    libc.usleep(100000)
print(f"returned {time.time():.3f}", file=sys.stderr, flush=True)
try:
    g.raise_if_stopped()
except Interrupted as e:
    g.restore()
    print(f"interrupted {e.signum} {e.moment}", file=sys.stderr, flush=True)
    sys.exit(e.exit_status)
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_inside_c_is_announced_at_once_and_acted_on_when_the_call_returns(sig):
    p = _spawn(_IN_C)
    _wait_line(p, "ready")
    time.sleep(0.3)
    p.send_signal(sig)
    t_sig = time.time()
    _, err = p.communicate(timeout=60)
    lines = err.splitlines()
    assert p.returncode == 128 + sig, err
    assert lines[0] == "" and lines[1] == (f"signal {int(sig)}: the command stops when the compile returns, before "
                                           f"anything of the run is written (again to stop now)")
    assert lines[2].startswith("returned ") and float(lines[2].split()[1]) > t_sig + 2  # the call was not cut short
    assert lines[3] == f"interrupted {int(sig)} compiling" and len(lines) == 4


def test_a_second_signal_stops_at_once_even_inside_c():
    p = _spawn(_IN_C)
    _wait_line(p, "ready")
    p.send_signal(signal.SIGINT)
    time.sleep(0.3)
    t0 = time.time()
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130 and time.time() - t0 < 2.5, err
    assert "returned" not in err and err.splitlines()[-1].startswith("nmrl: stopped at once by a second signal 2 "
                                                                      "while compiling")


def test_the_guard_puts_back_the_handlers_it_found():
    before = {s: signal.getsignal(s) for s in signals.SIGNALS}
    with signals.Guard() as g:
        assert signal.getsignal(signal.SIGINT) != before[signal.SIGINT]
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(0.2)
        assert g.signal == signal.SIGTERM
        with pytest.raises(signals.Interrupted) as e:
            g.raise_if_stopped()
        assert e.value.exit_status == 143
    assert {s: signal.getsignal(s) for s in signals.SIGNALS} == before


# ----------------------------------------------------------------------------- memory before allocation


def test_the_state_estimate_equals_the_bytes_allocated():
    L = learners.get("ac")
    cfg = options.build(L.config, preset="fast", num_envs=4, hidden_actor=16, hidden_critic=24, chunk_steps=10, steps=10).resolved()
    tr = L.make(cfg)
    key = jax.random.PRNGKey(0)
    ts = jax.jit(tr.init)(key)
    assert memory.state_bytes(tr.init, key) == sum(x.nbytes for x in jax.tree.leaves(ts))
    est = memory.estimate(tr.init, key, points=3)
    assert est.state_bytes == 3 * sum(x.nbytes for x in jax.tree.leaves(ts))


def test_absurd_sizes_are_refused_naming_the_estimate_and_the_machine():
    L = learners.get("ac")
    cfg = options.build(L.config, preset="fast", num_envs=8, hidden_actor=1_000_000_000, hidden_critic=8).resolved()
    tr = L.make(cfg)
    est = memory.estimate(tr.init, jax.random.PRNGKey(0))  # shapes only: nothing of this size is allocated
    total, avail = memory.machine_bytes()
    assert 0 < avail <= total
    assert est.state_bytes > 8 * 1_000_000_000 * 4  # at least 8 environments' traces of the actor's weights
    with pytest.raises(memory.TooLarge) as e:
        memory.preflight(est, "hidden_actor=1000000000", machine=(total, avail))
    msg = str(e.value)
    assert msg.startswith("hidden_actor=1000000000 needs about ") and f"{total / memory.GIB:,.1f} GiB" in msg
    warned: list[str] = []
    memory.preflight(memory.Estimate(1 << 20, 3 << 30), "n", warned.append, machine=(4 << 30, 2 << 30))
    assert len(warned) == 1 and "2.0 GiB of the machine's 4.0 GiB are available" in warned[0]
