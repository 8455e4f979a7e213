"""DeviceOwner: one worker thread alone calls a device; stop jumps the queue and never waits
behind a stuck call; calls after close are refused; a station closes its devices through
their owners.  The devices are small fakes at the hardware boundary that record who called
them, when, and whether two calls were ever inside at once."""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import pytest

from quickhealth.identify.errors import HardwareError
from quickhealth.station.hardware.owner import DeviceOwner


class Recorder:
    """A device that is not thread-safe and says so: it counts the calls inside it."""

    def __init__(self) -> None:
        self.inside = 0
        self.max_inside = 0
        self.threads: set[int] = set()
        self.log: list[tuple[str, float]] = []  # (call, time it began)
        self.release = threading.Event()
        self.closed_by: list[int] = []
        self._count = threading.Lock()  # only for the bookkeeping of this fake

    def _enter(self, what: str) -> None:
        with self._count:
            self.inside += 1
            self.max_inside = max(self.max_inside, self.inside)
            self.threads.add(threading.get_ident())
            self.log.append((what, time.monotonic()))

    def _leave(self) -> None:
        with self._count:
            self.inside -= 1

    def work(self, i: int, dt: float = 0.001) -> int:
        self._enter(f"work {i}")
        try:
            time.sleep(dt)
            return i * i
        finally:
            self._leave()

    def hang(self) -> str:
        """A call that does not return until the test releases it (a device that hangs)."""
        self._enter("hang")
        try:
            self.release.wait(10.0)
            return "back"
        finally:
            self._leave()

    def stop(self) -> str:
        self._enter("stop")
        self._leave()
        return "stopped"

    def close(self) -> None:
        self._enter("close")
        self.closed_by.append(threading.get_ident())
        self._leave()


def _calls(dev: Recorder) -> list[str]:
    return [w for w, _ in dev.log]


def test_calls_from_many_threads_never_overlap_inside_the_device() -> None:
    dev = Recorder()
    owner = DeviceOwner(dev, "recorder")
    results: dict[int, int] = {}
    errors: list[BaseException] = []

    def client(k: int) -> None:
        try:
            for j in range(20):
                i = 100 * k + j
                results[i] = owner.work(i)
        except BaseException as exc:  # noqa: BLE001 - the test inspects it
            errors.append(exc)

    threads = [threading.Thread(target=client, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30.0)
    assert not errors and len(results) == 160
    assert all(v == i * i for i, v in results.items())  # each caller got its own result
    assert dev.max_inside == 1  # never two calls inside the device at once
    assert dev.threads == {owner._thread.ident}  # and only the owner's thread ever called it
    assert owner.close()


def test_stop_jumps_the_queue_and_is_acted_on_within_100_ms() -> None:
    dev = Recorder()
    owner = DeviceOwner(dev, "recorder")
    first = threading.Thread(target=owner.work, args=(0, 0.05))  # in the device for 50 ms
    first.start()
    while not dev.log:
        time.sleep(0.001)
    queued = [threading.Thread(target=owner.work, args=(i,)) for i in range(1, 6)]
    for t in queued:
        t.start()
    time.sleep(0.01)  # the five are in the queue behind the first
    t0 = time.monotonic()
    assert owner.stop() == "stopped"
    took = time.monotonic() - t0
    for t in [first, *queued]:
        t.join(5.0)
    calls = _calls(dev)
    assert calls[0] == "work 0" and calls[1] == "stop", calls  # ahead of all five
    assert sorted(calls[2:]) == [f"work {i}" for i in range(1, 6)]
    began = dict((w, t) for w, t in dev.log)["stop"] - t0
    assert began < 0.1 and took < 1.0, (began, took)
    assert dev.max_inside == 1


def test_a_stuck_call_does_not_block_stop() -> None:
    """The device hangs inside a call: stop() does not wait behind it (nor enter the device
    from another thread); it says at once where the device is stuck.  The stop still runs
    first thing when the device returns."""
    dev = Recorder()
    owner = DeviceOwner(dev, "pan motor", act_within=0.1)
    stuck = threading.Thread(target=owner.hang)
    stuck.start()
    while not dev.log:
        time.sleep(0.001)
    later = threading.Thread(target=owner.work, args=(7,))
    later.start()
    time.sleep(0.01)
    t0 = time.monotonic()
    with pytest.raises(HardwareError) as err:
        owner.stop()
    assert time.monotonic() - t0 < 0.5
    msg = str(err.value)
    assert "pan motor" in msg and "inside hang()" in msg and "\n" not in msg
    assert _calls(dev) == ["hang"]  # nobody else went in
    dev.release.set()
    stuck.join(5.0)
    later.join(5.0)
    assert _calls(dev) == ["hang", "stop", "work 7"]
    assert dev.max_inside == 1


def test_calls_after_close_are_refused_and_none_racing_it_hangs() -> None:
    dev = Recorder()
    owner = DeviceOwner(dev, "stereo camera")
    outcomes: list[str] = []
    go = threading.Event()

    def client(k: int) -> None:
        go.wait()
        for j in range(50):
            try:
                owner.work(1000 * k + j)
                outcomes.append("ok")
            except HardwareError as exc:
                outcomes.append(str(exc))

    threads = [threading.Thread(target=client, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    go.set()
    time.sleep(0.02)
    assert owner.close() is True
    for t in threads:
        t.join(10.0)
    assert not any(t.is_alive() for t in threads)  # every caller got an answer
    assert len(outcomes) == 200
    refused = [o for o in outcomes if o != "ok"]
    assert refused and all("stereo camera is closed" in o for o in refused)
    assert _calls(dev)[-1] == "close" and dev.closed_by == [owner._thread.ident]
    with pytest.raises(HardwareError, match=r"the stereo camera is closed: work\(\) refused"):
        owner.work(1)
    with pytest.raises(HardwareError, match="closed"):
        owner.stop()
    assert owner.close() is True  # closing twice is harmless
    assert dev.max_inside == 1


def test_close_while_the_device_is_stuck_leaves_it_alone() -> None:
    dev = Recorder()
    owner = DeviceOwner(dev, "pan motor")
    stuck = threading.Thread(target=owner.hang)
    stuck.start()
    while not dev.log:
        time.sleep(0.001)
    t0 = time.monotonic()
    assert owner.close(timeout=0.2) is False
    assert time.monotonic() - t0 < 1.0
    assert dev.closed_by == []  # not closed from this thread while the worker is inside
    dev.release.set()
    stuck.join(5.0)
    owner._thread.join(5.0)
    assert dev.closed_by == [owner._thread.ident]  # closed by its owner once it returned


def test_station_close_goes_through_the_owners_and_skips_a_stuck_device(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Station.close never calls a device's close from outside its owner: a stuck pan motor
    is left open with a logged line (the raw ``motor.close`` among the closers is skipped),
    the camera is closed by its owner, the other closers still run."""
    from quickhealth.station import station as station_module
    from quickhealth.station.sim.fake_robot import FakeRobot
    from quickhealth.station.station import Station

    monkeypatch.setattr(station_module, "DEVICE_CLOSE_TIMEOUT_S", 0.2)
    motor, camera = Recorder(), Recorder()
    robot = FakeRobot()
    ran: list[str] = []
    station = Station(
        robot=robot,
        motor=motor,
        camera=camera,
        target=None,  # type: ignore[arg-type]
        T_instr_base=np.eye(4),
        T_flange_target=np.eye(4),
        closers=[lambda: ran.append("simulators"), motor.close, camera.close],
    )
    stuck = threading.Thread(target=station.motor.hang)
    stuck.start()
    while not motor.log:
        time.sleep(0.001)
    with caplog.at_level(logging.WARNING, logger="quickhealth.station.station"):
        station.close()
    assert "pan motor is still inside hang()" in caplog.text
    assert motor.closed_by == []  # left to its owner
    assert camera.closed_by == [station.camera._thread.ident]  # by its owner, once
    assert ran == ["simulators"]
    motor.release.set()
    stuck.join(5.0)
    station.motor._thread.join(5.0)
    assert motor.closed_by == [station.motor._thread.ident]
