"""Damaged autopilot logs (class 3): flipped bytes, a cut-out slice, a truncated
file, random data behind a log header.  Built from the real fixture logs in tests/data/real
(and from simulated boards written by thermonet's own writers, read back by pyulog and
pymavlink), at fixed seeded offsets.  Each is read with what was damaged and where said,
damaged samples dropped with a count, or refused with one line naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from thermonet.cli import main
from thermonet.core.errors import InputError
from thermonet.data.logs import read_log
from thermonet.data.logs.base import MAX_DAMAGED_FRACTION, screen_samples
from thermonet.data.logs.writers import write_log
from thermonet.sim.fcboard import simulate_board
from thermonet.workflows.calibrate import check_instance

REAL = Path(__file__).parent / "data" / "real"
ULG = REAL / "px4_ulog_sample" / "sample_log_small.ulg"
BIN = REAL / "ardupilot_bin_sample" / "test.BIN"


def _flip(data: bytes, seed: int, n: int, lo: int = 0, hi: int | None = None) -> bytes:
    rng = np.random.default_rng(seed)
    b = bytearray(data)
    for o in rng.integers(lo, hi or len(b), n):
        b[int(o)] ^= int(rng.integers(1, 256))
    return bytes(b)


def _info(path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    rc = main(["info", str(path)])
    cap = capsys.readouterr()
    return rc, cap.out, cap.err.strip()


@pytest.fixture(scope="module")
def board(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A simulated board (45 min at 1 Hz, 2,700 samples per instance) as .ulg and .bin."""
    tmp = tmp_path_factory.mktemp("board")
    return {ext: write_log(simulate_board("fc-board", autopilot=ap, seed=0), tmp / f"b{ext}")
            for ext, ap in ((".ulg", "px4"), (".bin", "ardupilot"))}


@pytest.mark.parametrize("fixture", [ULG, BIN])
@pytest.mark.parametrize("seed", range(6))
def test_flipped_bytes_in_real_logs_never_a_traceback(tmp_path, capsys, fixture, seed):
    """20 flipped bytes (in the ULog's definitions, anywhere in the DataFlash log): either
    read, with the damage said on stderr, or refused with one line naming the file."""
    data = fixture.read_bytes()
    bad = tmp_path / f"flipped{fixture.suffix}"
    bad.write_bytes(_flip(data, seed, 20, 0, 60_000 if fixture == ULG else None))
    rc, out, err = _info(bad, capsys)
    assert rc in (0, 1), err
    if rc == 1:
        assert len(err.splitlines()) == 1 and str(bad) in err and "Traceback" not in err
        assert "damaged" in err or "not a" in err, err
    else:
        assert "instance" in out
        assert "Traceback" not in err


def test_sound_logs_read_without_a_damage_word(board, capsys):
    # the real DataFlash fixture is the first 64 KiB of a longer log, cut inside a message:
    # it says so (tests/test_papercuts_data_messages.py:
    # test_the_real_bin_fixture_is_itself_cut_and_a_whole_log_is_not)
    for path in (ULG, board[".ulg"], board[".bin"]):
        log = read_log(path)
        assert log.damage == [] and log.unread_fraction == 0.0
        assert all(i.damaged == 0 and i.untrusted is None for i in log.instances)
        rc, out, err = _info(path, capsys)
        assert rc == 0 and err == "" and "damaged" not in out


@pytest.mark.parametrize("ext", [".ulg", ".bin"])
def test_bogus_temperature_sample_dropped_with_a_count(tmp_path, capsys, ext):
    """A −0.1 °C sample (a damaged temperature) in a board warming from 7 °C never reaches a
    fit: it is dropped, counted and placed in time; the instance keeps its slot."""
    log = simulate_board("fc-board", autopilot="px4" if ext == ".ulg" else "ardupilot", seed=1)
    gyro = next(i for i in log.instances if i.name == "gyro0")
    gyro.temperature_c = gyro.temperature_c.copy()
    gyro.temperature_c[1500] = -0.1
    path = write_log(log, tmp_path / f"bogus{ext}")
    back = {i.name: i for i in read_log(path).instances}
    assert back["gyro0"].temperature_c.min() > 6.0
    assert back["gyro0"].n_samples == gyro.n_samples - 1 and back["gyro0"].damaged == 1
    note = next(n for n in back["gyro0"].notes if n.startswith("damaged"))
    assert "1 of 2700" in note and "temperature" in note
    assert f"at t = {gyro.time_s[1500]:.1f} s" in note
    assert back["gyro0"].untrusted is None and check_instance(back["gyro0"]) is None
    # same instances (and so the same PX4 slots) as the sound board
    assert sorted(back) == sorted(i.name for i in log.instances)
    rc, out, err = _info(path, capsys)
    assert rc == 0 and "1 of 2700 samples dropped" in out


def test_dataflash_with_a_gap_cut_out_reads_the_rest_and_says_so(board, tmp_path, capsys):
    """pymavlink's index stops at the first damaged message; the reader goes on message by
    message: a quarter of the file cut out loses about a quarter of the samples, not 70 %."""
    data = board[".bin"].read_bytes()
    n = len(data)
    cut = tmp_path / "cut.bin"
    cut.write_bytes(data[: n // 3] + data[n // 3 + n // 4:])
    log = read_log(cut)
    counts = {i.name: i.n_samples for i in log.instances}
    assert set(counts) >= {"gyro0", "acc0", "gyro1", "acc1", "baro0"}
    assert all(1800 < c < 2300 for c in counts.values()), counts      # 2,700 × ~0.75
    gap = " ".join(log.notes)
    assert "gap" in gap and "from t = " in gap
    rc, out, err = _info(cut, capsys)
    assert rc == 0 and "gap" in out


def test_phantom_instances_from_a_flipped_instance_byte_are_dropped(board, tmp_path):
    """Flipped bytes that turn an IMU message's instance field into 154 or 235 make no
    instance of that number (it would take a calibration slot)."""
    data = bytearray(board[".bin"].read_bytes())
    # two IMU messages (A3 95, type 65; TimeUS then the instance byte) half-way through
    starts = [k for k in range(len(data) // 2, len(data) - 12)
              if data[k:k + 3] == b"\xa3\x95\x41" and data[k + 11] <= 2][:2]
    for k, phantom in zip(starts, (154, 235), strict=True):
        data[k + 11] = phantom
    bad = tmp_path / "flipped.bin"
    bad.write_bytes(bytes(data))
    log = read_log(bad)
    assert all(i.instance <= 2 for i in log.instances)
    assert any("damaged instance field" in d for d in log.damage)
    assert {i.name for i in log.instances} == {"gyro0", "acc0", "gyro1", "acc1", "gyro2",
                                               "acc2", "baro0", "mag0", "mag1"}


@pytest.mark.parametrize("seed", range(4))
def test_flipped_simulated_ulog_counts_what_it_drops(board, tmp_path, seed):
    bad = tmp_path / "flipped.ulg"
    bad.write_bytes(_flip(board[".ulg"].read_bytes(), seed, 8))
    log = read_log(bad)
    for inst in log.instances:
        assert inst.n_samples + inst.damaged <= 2700
        if inst.temperature_c is not None:
            assert 5.0 < inst.temperature_c.min() and inst.temperature_c.max() < 60.0
        assert np.all(np.diff(inst.time_s) >= 0) and inst.time_s.max() < 2800
        if inst.damaged:
            assert any(n.startswith(f"damaged: {inst.damaged} of ") for n in inst.notes)


def _first_data(data: bytes) -> int:
    """Byte offset of a ULog's first data (``D``) message: its definitions and subscriptions
    end there."""
    import struct

    pos = 16
    while pos + 3 <= len(data):
        size, mtype = struct.unpack_from("<HB", data, pos)
        if mtype == ord("D"):
            return pos
        pos += 3 + size
    raise AssertionError("no data message")


@pytest.mark.parametrize("what,expect", [
    ("random-after-ulog-header", "damaged: "),
    ("random-after-definitions", "damaged: "),
    ("random-after-dataflash-header", "damaged: "),
    ("ulog-cut-after-header", "no sensor topics"),
    ("ulog-magic-then-garbage", "damaged: a ULog header followed by data that cannot be parsed"),
])
def test_too_little_left_is_refused_in_one_line(board, tmp_path, capsys, what, expect):
    rng = np.random.default_rng(7)
    real = ULG.read_bytes()
    if what == "random-after-ulog-header":
        path, data = tmp_path / "r.ulg", real[:16] + rng.bytes(100_000)
    elif what == "random-after-definitions":
        # the definitions and subscriptions, cut where the first data message starts (found
        # by parsing: the magnetometers' format and parameters lengthen the definitions)
        good = board[".ulg"].read_bytes()
        path, data = tmp_path / "d.ulg", good[:_first_data(good)] + rng.bytes(400_000)
    elif what == "random-after-dataflash-header":
        path, data = tmp_path / "r.bin", b"\xa3\x95" + rng.bytes(100_000)
    elif what == "ulog-magic-then-garbage":
        path, data = tmp_path / "m.ulg", real[:7] + b"\xff" * 9 + rng.bytes(1000)
    else:
        path, data = tmp_path / "c.ulg", real[:200]
    path.write_bytes(data)
    for cmd in (["info", str(path)], ["calibrate", str(path), "--out", str(tmp_path / "o")]):
        assert main(cmd) == 1
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and str(path) in err and expect in err, err
    assert not (tmp_path / "o").exists()
    with pytest.raises(InputError):
        read_log(path)


def test_truncated_real_ulog_reads_what_is_there_and_says_where(tmp_path, capsys):
    data = ULG.read_bytes()
    cut = tmp_path / "half.ulg"
    cut.write_bytes(data[: len(data) // 2 + 7])
    log = read_log(cut)
    full = read_log(ULG)
    assert {i.name for i in log.instances} <= {i.name for i in full.instances}
    assert any("cut short?" in d for d in log.damage)
    rc, out, err = _info(cut, capsys)
    assert rc == 0 and "cut short?" in out


def test_instance_with_too_many_damaged_samples_is_left_out(tmp_path, capsys, caplog):
    """More than MAX_DAMAGED_FRACTION of an instance damaged: the rest is in doubt; the
    instance is left out with that reason, the others go on."""
    log = simulate_board("fc-board", autopilot="px4", seed=2)
    gyro = next(i for i in log.instances if i.name == "gyro1")
    temp = gyro.temperature_c.copy()
    bad = np.arange(100, 2700, 7)                       # 372 samples, 14 %
    assert bad.size > MAX_DAMAGED_FRACTION * temp.size
    temp[bad] = -40.0
    gyro.temperature_c = temp
    path = write_log(log, tmp_path / "bad.ulg")
    back = {i.name: i for i in read_log(path).instances}
    assert back["gyro1"].damaged == bad.size and back["gyro1"].untrusted
    reason = check_instance(back["gyro1"])
    assert reason is not None and reason.startswith(f"damaged: {bad.size} of 2700")
    assert check_instance(back["gyro0"]) is None
    rc, out, err = _info(path, capsys)
    assert rc == 0 and "not trusted — gyro1" in out
    # the reader's warning (stderr on the command line): what was dropped, which is untrusted
    assert any("damaged log" in r.getMessage() and "not trusted: gyro1" in r.getMessage()
               for r in caplog.records)


def test_screen_samples_rules():
    t = np.arange(100.0)
    v = np.zeros((100, 3))
    temp = np.linspace(10.0, 40.0, 100)
    keep, notes = screen_samples("gyro", t, v, temp)
    assert keep.all() and notes == []
    t2, v2, temp2 = t.copy(), v.copy(), temp.copy()
    t2[10] = 4.6e12            # a flipped high byte of the time
    v2[20, 1] = 3.4e38          # a flipped exponent
    temp2[30] = -0.1            # a bogus temperature
    temp2[40] = np.nan
    keep, notes = screen_samples("gyro", t2, v2, temp2, device_ids=np.r_[np.full(99, 7), 8])
    assert np.flatnonzero(~keep).tolist() == [10, 20, 30, 40, 99]
    text = " ".join(notes)
    for word in ("clock's order", "full scale", "off its neighbours", "not a number",
                 "device id"):
        assert word in text
    # a thermometer that steps by whole degrees, or a clock with a pause, is not damage
    steps = np.floor(np.linspace(10.0, 40.0, 100))
    pause = np.r_[np.arange(50.0), 500.0 + np.arange(50.0)]
    keep, notes = screen_samples("acc", pause, np.full((100, 3), 9.8), steps)
    assert keep.all() and notes == []


@pytest.mark.parametrize("ext", [".ulg", ".bin"])
def test_a_clock_that_jumps_back_is_refused_naming_the_jump(tmp_path, capsys, ext):
    """The board's clock set back by 600 s after its 1000th sample (the writer keeps each
    sensor's own order, as a logger writes it): sorting once interleaved the 10 minutes
    before the jump with those after it, silently; now calibrate refuses the log in one
    line naming the jump, as learn does."""
    autopilot = "px4" if ext == ".ulg" else "ardupilot"
    log = simulate_board(seed=0, rate_hz=1.0, autopilot=autopilot)
    t_jump = float(log.instances[0].time_s[999])
    for inst in log.instances:
        inst.time_s = inst.time_s.copy()
        inst.time_s[1000:] -= 600.0
    path = write_log(log, tmp_path / f"jump{ext}")
    with pytest.raises(InputError, match=rf"the clock jumps back by 599\.0 s at t = "
                                         rf"{t_jump:.1f} s \("):
        read_log(path)
    assert main(["calibrate", str(path), "--out", str(tmp_path / "cal"), "--no-compare"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{path}: the clock jumps back by 599.0 s" in err[0]
    assert not (tmp_path / "cal").exists()
    # the same samples in time order are the board's log, read as before
    assert len(read_log(write_log(simulate_board(seed=0, rate_hz=1.0, autopilot=autopilot),
                                  tmp_path / f"ok{ext}")).instances) == len(log.instances)
