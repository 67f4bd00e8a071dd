"""The simulated radio medium: lock-step virtual time, stations, frames on the air.

Conservative lock-step (BabbleSim): the medium owns true time. Each station runs until it
blocks in ``tun_wait``; only when every connected station waits does time move, to the
earliest of the stations' deadlines and the pending radio events. SPI transactions take no
virtual time. When every station waits in idle mode (nothing scheduled, only host input
expected), time is paced to real time so that host-side timeouts keep their meaning.

Time inside the medium is an integer number of picoseconds (``*_ps``) for exact ordering;
the tunnel speaks microseconds, the world model float seconds.

This module does no I/O: :mod:`uwbcal.medium.server` feeds it frames and sends what it
returns through each station's ``send`` callable.

Deferred receptions (speed, no change of result): at a frame's RMARKER the medium decides who
listens (and captures their LDE_RXANTD and epochs) but asks the World for the receptions
only in :meth:`Medium.settle`, so that the World works while the woken transmitter runs. The
server settles before it handles any station frame or control command and after each flush;
the medium settles before any other World call (but the clock: :meth:`Station.sys_time_units`
reads the clocks' own wander state, untouched by receptions), any event push, any event but
a TX end, and before time passes the earliest instant a reception could end (the frame's
end at its transmitter: arrival >= departure). So the World sees the same calls in the same
order as if it were asked at the RMARKER. (A reception ending at that very instant, at zero
distance, is delivered at the same virtual time, after the transmitter's wake.)
"""

from __future__ import annotations

import heapq
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import IO, Final

from uwbcal.dw1000 import DELAYED_TX_GRID, TIME_UNIT_S, TIMESTAMP_MOD
from uwbcal.medium import wire
from uwbcal.medium.airtime import FrameFormat
from uwbcal.medium.port import RadioWorld, TxFrame
from uwbcal.medium.registers import (
    CHAN_CTRL,
    LDE_IF,
    LDE_RXANTD_OFF,
    OTP_VTEMP_ADDR,
    Dw1000Model,
    RxFrame,
)

PS_PER_S: Final = 10**12
PS_PER_US: Final = 10**6

# Event kinds.
EV_RMARKER: Final = 0   # a frame's RMARKER leaves its transmitter
EV_TX_END: Final = 1    # the frame's last bit is out: TXFRS
EV_RX_END: Final = 2    # a reception completes: RXFCG
EV_RX_ON: Final = 3     # delayed RX enable


@dataclass(slots=True)
class Wait:
    """A station blocked in tun_wait."""

    seq: int
    deadline_ps: int
    idle: bool
    ignore_irq: bool
    snapshot: bool = False
    snapshot_time: bool = False


@dataclass(eq=False)
class Station:
    """One connected station: its register model, radio state and pending wait."""

    sid: int
    medium: Medium
    send: Callable[[bytes], None]
    model: Dw1000Model = field(init=False)
    wait: Wait | None = None
    epoch: int = 0                      #: bumped by TRXOFF/TX start: stale events are dropped
    rx_on: bool = False
    rx_since_ps: int = 0
    rx_busy: bool = False               #: a frame is being received
    tx_busy: bool = False
    log: IO[str] | None = None
    #: (now_ps, units) of the last clock reading: the World is asked once per instant.
    clock_at: tuple[int, float] = field(default=(-1, 0.0), init=False, repr=False)

    def __post_init__(self) -> None:
        self.model = Dw1000Model(host=self)
        self.model.otp[OTP_VTEMP_ADDR] = self.medium.world.otp_vtemp(self.sid)

    # ---- ChipHost --------------------------------------------------------------------
    def sys_time_units(self) -> float:
        """The station's DW1000 clock now, device units, unwrapped (a function of virtual time
        only: asked of the World once per instant)."""
        now = self.medium.now_ps
        at, units = self.clock_at
        if at != now:
            units = self.medium.world.local_units(self.sid, now / PS_PER_S)
            self.clock_at = (now, units)
        return units

    def start_tx(self, dx_units: int | None, tx_antd: int, fmt: FrameFormat) -> None:
        """Schedule a frame (delayed at unwrapped DX_TIME, or immediate).

        The World's part (emission time, TX_STAMP) is deferred to :meth:`Medium.settle`, which
        then fills TX_TIME (:meth:`Dw1000Model.tx_stamped`) and queues the RMARKER."""
        self.epoch += 1
        self.rx_on = False
        self.rx_busy = False
        self.tx_busy = True
        if dx_units is None:
            # Immediate: the preamble starts at the next 512-unit tick, the RMARKER follows it.
            now = int(self.sys_time_units())
            dx_units = (now | (DELAYED_TX_GRID - 1)) + 1 + int(fmt.shr_s() / TIME_UNIT_S)
        dx, epoch = dx_units, self.epoch
        ctrl = self.model.get(CHAN_CTRL, 0, 4)
        gain, payload = self.model.tx_gain_octet(), self.model.tx_payload(fmt)

        def emit() -> None:
            t_s, stamp = self.medium.world.delayed_tx(self.sid, dx, tx_antd)
            self.model.tx_stamped(stamp, tx_antd)
            frame = TxFrame(tx_station=self.sid, t_rmarker_s=t_s, gain_octet=gain, fmt=fmt,
                            channel=ctrl & 0xF, payload=payload)
            self.medium.push(round(t_s * PS_PER_S), EV_RMARKER, self, (epoch, frame, ctrl))

        self.medium.defer(emit, tx=True)

    def radio_off(self) -> None:
        """TRXOFF: a pending TX and any reception are cancelled."""
        self.epoch += 1
        self.rx_on = False
        self.rx_busy = False
        self.tx_busy = False

    def rx_enable(self, at_units: float | None) -> None:
        """Receiver on, now or at a time on this clock."""
        if at_units is None:
            self.rx_on = True
            self.rx_busy = False
            self.rx_since_ps = self.medium.now_ps
        else:
            t_s = self.medium.world.true_time(self.sid, at_units)
            self.medium.push(round(t_s * PS_PER_S), EV_RX_ON, self, (self.epoch,))

    def temperature_c(self) -> float:
        """Chip temperature now, degC."""
        return self.medium.world.temperature_c(self.sid, self.medium.now_ps / PS_PER_S)


class Medium:
    """Stations, the event queue and virtual time. Not thread-safe; one event loop drives it."""

    def __init__(self, world: RadioWorld, *, pace_idle: bool = True,
                 log_dir: str | None = None, clock: Callable[[], float] = time.monotonic) -> None:
        self.world = world
        self.expected = set(world.station_ids())
        self.stations: dict[int, Station] = {}
        self.now_ps = 0
        self.pace_idle = pace_idle
        self.log_dir = log_dir
        self._clock = clock
        self._events: list[tuple[int, int, int, Station, tuple[object, ...]]] = []
        self._order = 0
        self._anchor: tuple[float, int] | None = None   # (wall s, virtual ps) while all idle
        self.frames = 0
        self.receptions = 0
        #: World work not done yet, in call order (see the module doc): a delayed TX's emission
        #: (``_deferred_tx``: settled before time moves) or a frame's receptions (time may move
        #: up to ``_deferred_bound``, the earliest instant one could end)
        self._deferred: list[Callable[[], None]] = []
        self._deferred_tx = False
        self._deferred_bound = 0
        self.paced_ps = 0          #: virtual time spent paced to real time (every station idle)
        self.idle_waits = 0        #: tun_wait calls in idle mode

    # ---- events ---------------------------------------------------------------------
    def push(self, t_ps: int, kind: int, st: Station, data: tuple[object, ...]) -> None:
        """Queue an event at true time t_ps."""
        if self._deferred:
            self.settle()
        self._order += 1
        heapq.heappush(self._events, (max(t_ps, self.now_ps), self._order, kind, st, data))

    def _run_event(self, kind: int, st: Station, data: tuple[object, ...]) -> None:
        if self._deferred and kind != EV_TX_END:
            self.settle()
        if kind == EV_RMARKER:
            epoch, frame, ctrl = data
            assert isinstance(frame, TxFrame) and isinstance(ctrl, int)
            if epoch != st.epoch or self.stations.get(st.sid) is not st:
                return
            self._on_air(st, frame, ctrl)
        elif kind == EV_TX_END:
            (epoch,) = data
            if epoch != st.epoch:
                return
            st.tx_busy = False
            if st.model.tx_done():
                st.rx_enable(None)
        elif kind == EV_RX_END:
            epoch, rxf = data
            if epoch != st.epoch or not st.rx_on:
                return
            assert isinstance(rxf, RxFrame)
            st.rx_on = False
            st.rx_busy = False
            st.model.deliver(rxf)
            self.receptions += 1
            if st.log is not None:
                st.log.write(f"{self.now_ps / PS_PER_S:.9f} RX {rxf.payload[:12].hex()} "
                             f"stamp={rxf.rec.stamp_units % TIMESTAMP_MOD}\n")
        elif kind == EV_RX_ON:
            (epoch,) = data
            if epoch == st.epoch:
                st.rx_enable(None)

    def _on_air(self, tx: Station, frame: TxFrame, ctrl: int) -> None:
        """A frame's RMARKER: decide every listening receiver's outcome (physics)."""
        self.frames += 1
        t_rm_ps = self.now_ps
        tail_ps = round(frame.fmt.tail_s() * PS_PER_S)
        shr_ps = round(frame.fmt.shr_s() * PS_PER_S)
        self.push(t_rm_ps + tail_ps, EV_TX_END, tx, (tx.epoch,))
        if tx.log is not None:
            tx.log.write(f"{frame.t_rmarker_s:.9f} TX {frame.payload[:12].hex()} "
                         f"gain={frame.gain_octet:#04x}\n")
        listening: list[Station] = []
        for rx in self.stations.values():
            if rx is tx or not rx.rx_on or rx.rx_busy or rx.tx_busy:
                continue
            if rx.rx_since_ps > t_rm_ps - shr_ps:
                continue  # the receiver came on after the preamble started
            rctrl = rx.model.get(CHAN_CTRL, 0, 4)
            # Channel (RX_CHAN vs TX_CHAN), PRF and preamble code must match.
            if ((rctrl >> 4) & 0xF) != (ctrl & 0xF) or ((rctrl >> 18) & 3) != ((ctrl >> 18) & 3) \
                    or ((rctrl >> 27) & 0x1F) != ((ctrl >> 22) & 0x1F):
                continue
            listening.append(rx)
        if not listening:
            return
        # The receptions are asked of the World in settle(); a reception cannot end before
        # the frame's own end at its transmitter (arrival >= departure).
        rx_antd = {rx.sid: rx.model.get(LDE_IF, LDE_RXANTD_OFF, 2) for rx in listening}
        epochs = [rx.epoch for rx in listening]

        def receive() -> None:
            recs = self.world.receive(frame, [rx.sid for rx in listening], rx_antd)
            for rx, epoch in zip(listening, epochs, strict=True):
                rec = recs.get(rx.sid)
                if rec is None:
                    continue
                rx.rx_busy = True
                rxf = RxFrame(rec=rec, payload=frame.payload, fmt=frame.fmt)
                self.push(round(rec.arrival_s * PS_PER_S) + tail_ps, EV_RX_END, rx, (epoch, rxf))

        self.defer(receive, tx=False)
        self._deferred_bound = min(t_rm_ps, round(frame.t_rmarker_s * PS_PER_S)) + tail_ps

    def defer(self, job: Callable[[], None], *, tx: bool) -> None:
        """Queue World work for :meth:`settle` (tx: a delayed TX's emission)."""
        self._deferred.append(job)
        self._deferred_tx = self._deferred_tx or tx

    @property
    def deferred(self) -> bool:
        """Receptions are waiting for :meth:`settle`."""
        return bool(self._deferred)

    def settle(self) -> None:
        """Do the deferred World work, in order (see the module doc)."""
        while self._deferred:
            jobs, self._deferred = self._deferred, []
            self._deferred_tx = False
            for job in jobs:
                job()

    # ---- stations -------------------------------------------------------------------
    def hello(self, sid: int, send: Callable[[bytes], None]) -> Station:
        """A station connected (or reconnected after a restart)."""
        self.settle()
        old = self.stations.get(sid)
        if old is not None:
            old.radio_off()
        st = Station(sid=sid, medium=self, send=send)
        if self.log_dir is not None:
            st.log = open(f"{self.log_dir}/station{sid}.log", "a", buffering=1 << 16)  # noqa: SIM115
        self.stations[sid] = st
        self.expected.add(sid)
        return st

    def bye(self, st: Station) -> None:
        """A station disconnected: the others go on without it."""
        self.settle()
        if self.stations.get(st.sid) is st:
            del self.stations[st.sid]
            self.expected.discard(st.sid)
            st.radio_off()
            if st.log is not None:
                st.log.close()

    def start_wait(self, st: Station, seq: int, deadline_us: int, mode: int) -> None:
        """tun_wait: the station blocks."""
        st.wait = Wait(seq=seq, deadline_ps=deadline_us * PS_PER_US,
                       idle=bool(mode & wire.MODE_IDLE), ignore_irq=bool(mode & wire.MODE_IGNORE_IRQ),
                       snapshot=bool(mode & wire.MODE_SNAPSHOT),
                       snapshot_time=bool(mode & wire.MODE_SNAPSHOT_TIME))
        if mode & wire.MODE_IDLE:
            self.idle_waits += 1

    def cancel(self, st: Station) -> None:
        """tun_cancel: answer the pending wait now (at the paced virtual time if pacing)."""
        if st.wait is None:
            return
        self.settle()
        if self._anchor is not None:
            wall0, virt0 = self._anchor
            paced = virt0 + int((self._clock() - wall0) * PS_PER_S)
            limit = self._next_time()
            t = max(self.now_ps, min(paced, limit if limit is not None else paced))
            self.paced_ps += t - self.now_ps
            self.now_ps = t
            self._drain_events()
        self._wake(st)

    def _wake(self, st: Station) -> None:
        w = st.wait
        assert w is not None
        st.wait = None
        self._anchor = None
        payload = wire.WAIT_RESP.pack(self.now_ps // PS_PER_US, int(st.model.irq))
        if w.snapshot:
            payload += st.model.snapshot(w.snapshot_time)
        st.send(wire.response(wire.TUN_WAIT, w.seq, payload))

    def _next_time(self) -> int | None:
        t: int | None = self._events[0][0] if self._events else None
        for st in self.stations.values():
            if st.wait is not None and (t is None or st.wait.deadline_ps < t):
                t = st.wait.deadline_ps
        return t

    def _drain_events(self) -> None:
        ev = self._events
        while ev and ev[0][0] <= self.now_ps:
            _, _, kind, st, data = heapq.heappop(ev)
            self._run_event(kind, st, data)

    def advance(self) -> float | None:
        """Move virtual time as far as lock-step allows.

        Returns None when the medium must wait for a station's next frame, or a wall-clock
        delay (s) after which to call again (pacing to real time while every station idles).
        """
        if self._deferred_tx:
            self.settle()      # the RMARKER's time comes from the World
        while True:
            stations = self.stations
            # A wait that is already over (IRQ asserted, deadline reached) ends at once: that
            # needs no time to pass, so it does not wait for the other stations.
            woke = False
            for st in list(stations.values()):
                w = st.wait
                if w is not None and (w.deadline_ps <= self.now_ps or (not w.ignore_irq and st.model.irq)):
                    self._wake(st)
                    woke = True
            if woke or len(stations) < len(self.expected) or not stations:
                return None
            all_idle = True
            for st in stations.values():
                w = st.wait
                if w is None:
                    return None
                all_idle = all_idle and w.idle
            t_next = self._next_time()
            assert t_next is not None
            if all_idle and self.pace_idle:
                wall = self._clock()
                if self._anchor is None:
                    self._anchor = (wall, self.now_ps)
                wall0, virt0 = self._anchor
                due = wall0 + (t_next - virt0) / PS_PER_S
                if due > wall:
                    return due - wall
                self.paced_ps += max(0, t_next - self.now_ps)
            if self._deferred and t_next > self._deferred_bound:
                self.settle()   # a reception may end before t_next
                continue
            self.now_ps = max(self.now_ps, t_next)
            self._drain_events()
