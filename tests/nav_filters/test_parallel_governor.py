"""The switch that forces every row kernel serial (``kernels.serial_rows``) and the governor that picks parallel
or serial row kernels by measuring both (``nav_filters.parallel_governor``), on a fake clock: it runs the faster
mode, probes the other, leaves units marked not comparable out, does not flip on one outlier, honours
``'always'`` / ``'never'`` and does nothing on one numba thread or below ``PARALLEL_MIN_BATCH`` rows."""
import re

import numpy as np
import pytest

from nav_filters import kernels
from nav_filters.forms import kf
from nav_filters.kernels import PARALLEL_MIN_BATCH, row_chunks, row_kernel, rows_forced_serial, serial_rows
from nav_filters.parallel_governor import ParallelGovernor, check_policy

B = PARALLEL_MIN_BATCH + 6


# ----------------------------------------------------------------------------- serial_rows
def test_serial_rows_makes_every_row_kernel_serial_and_restores():
    parallel_chunks = row_chunks(B)
    assert parallel_chunks > 1 and row_kernel("s", "p", B) == ("p", parallel_chunks)
    with serial_rows():
        assert rows_forced_serial()
        assert row_chunks(B) == 1 and row_kernel("s", "p", B) == ("s", 1)
        with serial_rows(False):  # nested, "change nothing": still serial
            assert row_chunks(B) == 1
        assert row_chunks(B) == 1  # the inner exit restored the outer setting
    assert not rows_forced_serial() and row_chunks(B) == parallel_chunks
    with serial_rows(False):
        assert row_chunks(B) == parallel_chunks


def test_serial_rows_restores_on_an_exception():
    with pytest.raises(RuntimeError, match="boom"):
        with serial_rows():
            assert row_chunks(B) == 1
            raise RuntimeError("boom")
    assert not rows_forced_serial() and row_chunks(B) > 1


def test_the_direct_batch_size_sites_follow_serial_rows(monkeypatch):
    """``scale_symmetric`` and ``joseph_update`` chose their variant by the batch size alone before; they launch
    the serial variant inside ``serial_rows``, with the same bits."""
    calls = []

    def spy(name, fn):
        def wrapped(*a):
            calls.append(name)
            return fn(*a)
        return wrapped

    for mod, ser, par in ((kernels, "_scale_serial", "_scale_parallel"), (kf, "_joseph_serial", "_joseph_parallel")):
        monkeypatch.setattr(mod, ser, spy("serial", getattr(mod, ser)))
        monkeypatch.setattr(mod, par, spy("parallel", getattr(mod, par)))
    rng = np.random.default_rng(0)
    n, m = 17, 6
    A = rng.normal(size=(B, n, n))
    P = A @ A.transpose(0, 2, 1) + n * np.eye(n)
    R = np.broadcast_to(np.eye(m), (B, m, m)).copy()
    args = (P, rng.normal(size=(B, n)), rng.normal(size=(B, m, n)), R, rng.normal(size=(B, m)))
    s = rng.uniform(0.5, 2, (B, m))
    par = (kernels.scale_symmetric(R, s), kf.joseph_update(*args))
    assert calls == ["parallel", "parallel"]
    with serial_rows():
        ser = (kernels.scale_symmetric(R, s), kf.joseph_update(*args))
    assert calls[2:] == ["serial", "serial"]
    np.testing.assert_array_equal(par[0], ser[0])
    for a, b in zip(par[1], ser[1]):
        np.testing.assert_array_equal(a, b)


# ----------------------------------------------------------------------------- the governor, on a fake clock
class FakeClock:
    """A wall clock that the test advances; ``i`` counts the units run (the cost functions' unit index)."""

    def __init__(self):
        self.t = 0.0
        self.i = 0

    def __call__(self):
        return self.t


def _gov(policy="auto", **kw):
    clock = FakeClock()
    kw.setdefault("threads", 2)
    return ParallelGovernor(policy, batch_size=B, clock=clock, **kw), clock


def _drive(gov, clock, n, cost, comparable=lambda i, mode: True):
    """Run ``n`` units; unit i (counted over the clock's life) in mode m takes ``cost(i, m)`` seconds of the fake
    clock and is comparable where ``comparable(i, m)``. Returns the modes of the ``n`` units."""
    modes = []
    for _ in range(n):
        i = clock.i
        clock.i += 1
        with gov.unit() as u:
            assert rows_forced_serial() == (u.mode == "serial")  # the unit runs in its mode
            modes.append(u.mode)
            clock.t += cost(i, u.mode)
            u.comparable = comparable(i, u.mode)
        assert not rows_forced_serial()
    return modes


START = ["parallel", "serial"] + ["parallel", "serial"] * 3  # warm-ups, then 3 samples of each mode


@pytest.mark.parametrize("fast", ["parallel", "serial"])
def test_it_runs_the_faster_mode_and_probes_the_other(fast):
    gov, clock = _gov(probe_every=20)
    slow = "serial" if fast == "parallel" else "parallel"
    modes = _drive(gov, clock, 8 + 200, lambda i, m: 1.0 if m == fast else 2.0)
    assert modes[:8] == START and gov.preferred == fast and gov.switches == (fast == "serial")
    probes = [i for i, m in enumerate(modes) if i >= 8 and m == slow]
    # a probe every 20 units x the other mode's slowdown (2): one unit of the other mode, then 40 of the faster
    assert probes == list(range(8 + 40, 208, 41)) and gov.probes == len(probes)
    assert gov.summary()["median_s"] == {fast: 1.0, slow: 2.0}


def test_the_probe_interval_stretches_with_the_slowdown_up_to_max_stretch():
    gov, clock = _gov(probe_every=10, max_stretch=3.0)
    modes = _drive(gov, clock, 8 + 100, lambda i, m: 1.0 if m == "serial" else 5.0)  # 5x slower: stretch 3
    probes = [i for i, m in enumerate(modes) if i >= 8 and m == "parallel"]
    assert probes == [38, 69, 100]


def test_it_follows_a_change_of_the_load_both_ways():
    """Parallel fast, then a competing process makes it 4x slower (switch to serial within a few units, not one
    probe interval), then the core is free again (back to parallel after the next probe and its confirmations)."""
    gov, clock = _gov(probe_every=20)

    def cost(i, m):
        if m == "serial":
            return 2.0
        return 4.0 if 100 <= i < 400 else 1.0

    modes = _drive(gov, clock, 600, cost)
    assert modes[60:100].count("parallel") == 39  # one probe (at 89)
    assert modes[103:400].count("serial") >= 285  # switched after 3 slow units (the median of 5), then probes
    back = next(i for i in range(400, 600) if modes[i:i + 5] == ["parallel"] * 5)
    assert back <= 400 + 20 * 2 + 5  # within one probe interval (stretch 4/2) and the confirming probes
    assert modes[-50:].count("parallel") >= 47 and gov.preferred == "parallel" and gov.switches == 2


def test_units_marked_not_comparable_are_left_out():
    """Every 4th unit also resets episodes; such units are fast in serial and very slow in parallel (if they were
    compared, serial would win); the plain units are faster in parallel, which the governor keeps."""
    gov, clock = _gov(probe_every=20)
    reset = lambda i, m: i % 4 == 3  # noqa: E731

    def cost(i, m):
        if reset(i, m):
            return 0.1 if m == "serial" else 50.0
        return 1.0 if m == "parallel" else 2.0

    modes = _drive(gov, clock, 300, cost, comparable=lambda i, m: not reset(i, m))
    assert gov.preferred == "parallel" and gov.switches == 0
    assert set(gov.samples["parallel"]) == {1.0} and set(gov.samples["serial"]) == {2.0}
    assert gov.excluded["parallel"] and set(gov.excluded["parallel"]) == {50.0}
    # a probe that falls on a reset unit is repeated at the next unit
    repeated = 0
    for i in range(20, 299):
        if modes[i] == "serial" and reset(i, "serial"):
            repeated += 1
            assert modes[i + 1] == "serial"
    assert gov.probes > 5 and repeated >= 1


def test_where_every_unit_is_marked_not_comparable_they_are_compared():
    """One-step episodes: every step resets. After 2 x window such units in a row the governor takes them as the
    usual unit (else it would alternate the modes for ever) and settles on the faster mode."""
    gov, clock = _gov(probe_every=20)
    modes = _drive(gov, clock, 100, lambda i, m: 1.0 if m == "serial" else 3.0, comparable=lambda i, m: False)
    assert set(gov.samples["serial"]) == {1.0} and set(gov.samples["parallel"]) == {3.0}
    assert len(gov.excluded["parallel"]) + len(gov.excluded["serial"]) > 0  # the first ones were kept apart
    assert gov.preferred == "serial" and modes[40:].count("serial") >= 58


def test_one_outlier_does_not_flip_the_mode():
    gov, clock = _gov(probe_every=20)
    _drive(gov, clock, 30, lambda i, m: 1.0 if m == "parallel" else 2.0)
    assert gov.preferred == "parallel" and gov.next_mode() == "parallel"
    # one very slow parallel unit (a page-fault storm, another process's burst), then normal ones
    _drive(gov, clock, 1, lambda i, m: 100.0)
    _drive(gov, clock, 5, lambda i, m: 1.0 if m == "parallel" else 2.0)
    assert gov.preferred == "parallel" and gov.switches == 0
    # one very fast serial probe: confirmed by the next probe, which is slow: no switch
    for _ in range(100):  # (bounded: a governor that never probes fails here, not hangs)
        if gov.next_mode() == "serial":
            break
        _drive(gov, clock, 1, lambda i, m: 1.0)
    serial_costs = iter([0.01, 2.0])
    modes = _drive(gov, clock, 3, lambda i, m: next(serial_costs) if m == "serial" else 1.0)
    assert modes == ["serial", "serial", "parallel"]  # the probe and its confirmation
    assert gov.preferred == "parallel" and gov.switches == 0


def test_a_sustained_faster_probe_switches():
    """The counterpart of the outlier test (so it can fail): serial probes that keep winning do switch."""
    gov, clock = _gov(probe_every=20)
    _drive(gov, clock, 30, lambda i, m: 1.0 if m == "parallel" else 2.0)
    modes = _drive(gov, clock, 60, lambda i, m: 1.0 if m == "parallel" else 0.5)
    assert gov.preferred == "serial" and gov.switches == 1
    first = modes.index("serial")
    assert modes[first:first + 4] == ["serial"] * 4  # the probe, two confirmations, then serial as preferred


def test_an_old_median_of_the_other_mode_does_not_switch_by_itself():
    """Serial was measured at 2.0 at the start and is 3.0 now (unknown to the governor); a burst makes parallel
    2.5 for 6 units. A rule comparing the medians would switch to serial (2.5 > 2.0 / 0.95); the governor probes
    serial afresh instead, sees 3.0, and stays parallel."""
    gov, clock = _gov(probe_every=20)
    _drive(gov, clock, 30, lambda i, m: 1.0 if m == "parallel" else 2.0)
    modes = _drive(gov, clock, 40, lambda i, m: 3.0 if m == "serial" else (2.5 if 30 <= i < 36 else 1.0))
    assert gov.switches == 0 and gov.preferred == "parallel"
    assert 1 <= modes[:10].count("serial") <= 2  # the early probe (and none other inside the burst)
    assert list(gov.samples["serial"])[-1] == 3.0


def test_a_short_burst_costs_a_few_units_not_a_probe_interval():
    """Parallel 1.0, serial 2.0; parallel 4.0 during units 100-109. The governor switches to serial within the
    burst and, probing the mode it left after probe_min units (then 2x, 4x, ...), is back on parallel within a
    dozen units of the burst's end, not one steady interval (20 x 2 = 40 units) later."""
    gov, clock = _gov(probe_every=20, probe_min=4)
    modes = _drive(gov, clock, 200, lambda i, m: 2.0 if m == "serial" else (4.0 if 100 <= i < 110 else 1.0))
    assert "serial" in modes[100:110] and gov.switches == 2 and gov.preferred == "parallel"
    back = next(i for i in range(110, 200) if modes[i:i + 5] == ["parallel"] * 5)
    assert back <= 110 + 12


@pytest.mark.parametrize("policy, mode", [("always", "parallel"), ("never", "serial")])
def test_always_and_never_are_fixed_and_measure_nothing(policy, mode):
    def no_clock():
        raise AssertionError("a fixed policy reads no clock")

    gov = ParallelGovernor(policy, batch_size=B, threads=2, clock=no_clock)
    assert not gov.active and gov.preferred == mode
    for _ in range(40):
        with gov.unit() as u:
            assert u.mode == mode and rows_forced_serial() == (mode == "serial")
            assert (row_chunks(B) == 1) == (mode == "serial")
    with gov.preferred_mode():
        assert rows_forced_serial() == (mode == "serial")
    assert gov.units == 0 and not gov.samples["parallel"] and not gov.samples["serial"]


@pytest.mark.parametrize("threads, batch", [(1, B), (2, PARALLEL_MIN_BATCH - 1)])
def test_auto_does_nothing_on_one_thread_or_few_rows(threads, batch):
    def no_clock():
        raise AssertionError("an inactive governor reads no clock")

    gov = ParallelGovernor("auto", batch_size=batch, threads=threads, clock=no_clock)
    assert not gov.active
    for _ in range(20):
        with gov.unit() as u:
            assert u.mode == "parallel" and not rows_forced_serial()  # the fixed rule decides
    assert gov.units == 0 and gov.summary()["median_s"] == {"parallel": None, "serial": None}


def test_auto_asks_numba_for_its_threads():
    import numba
    gov = ParallelGovernor("auto", batch_size=B)
    assert gov.threads == numba.get_num_threads() and gov.active == (numba.get_num_threads() > 1)


def test_a_unit_that_raises_records_nothing_and_restores():
    gov, clock = _gov()
    with pytest.raises(ValueError):
        with gov.unit():
            clock.t += 1.0
            raise ValueError("bad action")
    assert gov.units == 0 and not rows_forced_serial()


@pytest.mark.parametrize("bad", ["sometimes", "Auto", None, True, 1])
def test_an_unknown_policy_is_one_clear_error(bad):
    msg = f"parallel_kernels must be one of 'auto', 'always', 'never', got {bad!r}"
    with pytest.raises(ValueError, match=f"^{re.escape(msg)}$"):
        check_policy(bad)
    with pytest.raises(ValueError, match="parallel_kernels must be one of"):
        ParallelGovernor(bad)


@pytest.mark.parametrize("kw, name", [(dict(probe_every=1), "probe_every"), (dict(window=0), "window"),
                                      (dict(start_samples=6), "start_samples"), (dict(margin=1.0), "margin"),
                                      (dict(max_stretch=0.5), "max_stretch"), (dict(probe_min=0), "probe_min"),
                                      (dict(confirmations=0), "confirmations")])
def test_bad_settings_name_the_argument(kw, name):
    with pytest.raises(ValueError, match=f"^{name} must be"):
        ParallelGovernor("auto", threads=2, **kw)
