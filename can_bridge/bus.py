"""The CAN bus: configuration, opening with clear errors, and a self-healing wrapper.

Any python-can interface works.  ``socketcan`` on ``vcan0`` is the default on Linux; where
the kernel has no SocketCAN (containers, some CI machines) use ``udp_multicast`` with an
interface-local IPv6 group (``ff11::…``, never leaves the host; every process on the group
sees every frame, its own included) or ``virtual`` (within one process).

:class:`ResilientBus` is what the bridge uses: it opens lazily, never raises on send or
receive, counts what it drops, and after an error closes the bus and reopens it with an
exponential backoff.
"""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import logging
import math
import re
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import can

from damper_emulator.errors import UserError, one_line

if TYPE_CHECKING:
    from can_bridge.can_log import CanLog

__all__ = [
    "BusConfig",
    "CanBusError",
    "ResilientBus",
    "open_bus",
    "socketcan_available",
    "socketcan_problem",
]

_log = logging.getLogger(__name__)

#: Classic CAN's highest bit rate [bit/s].
MAX_BITRATE = 1_000_000

#: Longest single wait in an underlying bus's recv [s] (see ResilientBus.recv).
_RECV_SLICE_S = 0.2


class CanBusError(UserError, RuntimeError):
    """A CAN bus cannot be opened (one line: interface, channel, cause, remedy)."""


@dataclass(frozen=True)
class BusConfig:
    """Which python-can bus to open.

    Parameters
    ----------
    interface : str
        A python-can interface name (``can.VALID_INTERFACES``): ``socketcan``,
        ``udp_multicast``, ``virtual``, ``pcan``, ...
    channel : str
        The interface's channel: ``vcan0``/``can0`` for socketcan, any name for virtual, a
        multicast group for udp_multicast, optionally with a UDP port: ``ff11::1``,
        ``[ff11::1]:43114`` or ``239.0.0.1:43114`` (python-can's default port is 43113).
        Use interface-local IPv6 groups (``ff11::…``): they never leave the host.  Buses on
        the same port see each other's frames whatever their group (python-can binds the
        port on every address and Linux delivers every group joined on the host), so give
        independent set-ups on one host different ports.
    bitrate : int
        Nominal bit rate [bit/s], 1..1 000 000; passed to the interface (socketcan takes it
        from ``ip link`` instead and ignores it).
    receive_own_messages : bool
        Receive the frames this bus sends (not supported by udp_multicast, which delivers
        them anyway).
    receive_ids : tuple of int
        Receive only data frames with these 11-bit identifiers (python-can filters: in the
        kernel for socketcan, before any decoding for the others); empty: all frames.

    Raises
    ------
    ValueError
        One line naming the bad field.
    """

    interface: str = "socketcan"
    channel: str = "vcan0"
    bitrate: int = 500_000
    receive_own_messages: bool = False
    receive_ids: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        if not all(isinstance(i, int) and not isinstance(i, bool) and 0 <= i <= 0x7FF
                   for i in self.receive_ids):
            raise UserError(f"receive_ids must be 11-bit identifiers, got {self.receive_ids!r}")
        if self.interface not in can.VALID_INTERFACES:
            raise UserError(f"can interface {self.interface!r} is not a python-can interface "
                             f"(one of {', '.join(sorted(can.VALID_INTERFACES))})")
        if not isinstance(self.channel, str) or not self.channel.strip():
            raise UserError(f"can channel must be a non-empty string, got {self.channel!r}")
        if (isinstance(self.bitrate, bool) or not isinstance(self.bitrate, int)
                or not 0 < self.bitrate <= MAX_BITRATE):
            raise UserError(f"can bitrate must be an integer 1..{MAX_BITRATE} bit/s, "
                             f"got {self.bitrate!r}")
        if not isinstance(self.receive_own_messages, bool):
            raise UserError("receive_own_messages must be a bool, got "
                             f"{self.receive_own_messages!r}")
        if self.interface == "udp_multicast":
            _split_udp_channel(self.channel)
            if self.receive_own_messages:
                raise UserError("udp_multicast does not support receive_own_messages=True "
                                 "(it delivers the bus's own frames anyway)")

    def bus_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of ``can.Bus`` for this configuration."""
        kwargs: dict[str, Any] = dict(interface=self.interface, channel=self.channel,
                                      bitrate=self.bitrate,
                                      receive_own_messages=self.receive_own_messages)
        if self.receive_ids:
            kwargs["can_filters"] = [{"can_id": i, "can_mask": 0x7FF, "extended": False}
                                     for i in self.receive_ids]
        if self.interface == "udp_multicast":
            group, port = _split_udp_channel(self.channel)
            kwargs["channel"] = group
            if port is not None:
                kwargs["port"] = port
        return kwargs

    @property
    def label(self) -> str:
        """``interface:channel``, for messages."""
        return f"{self.interface}:{self.channel}"


def _split_udp_channel(channel: str) -> tuple[str, int | None]:
    """``GROUP``, ``[IPV6_GROUP]:PORT`` or ``IPV4_GROUP:PORT`` → (group, port or None)."""
    port: int | None = None
    match = re.fullmatch(r"\[([^\]]+)\](?::(\d+))?", channel)
    if match:
        group, port_text = match.groups()
    elif channel.count(":") == 1:
        group, port_text = channel.split(":")
    else:
        group, port_text = channel, None
    if port_text is not None:
        port = int(port_text) if port_text.isdigit() else -1
        if not 0 < port < 65536:
            raise UserError(f"udp_multicast channel {channel!r}: port must be 1..65535")
    try:
        address = ipaddress.ip_address(group.split("%")[0])
    except ValueError:
        address = None
    if address is None or not address.is_multicast:
        raise UserError(f"udp_multicast channel must be a multicast group, optionally with a "
                         f"port ([ff11::1]:43113), got {channel!r}")
    return group, port


def socketcan_problem(channel: str | None = "vcan0") -> str | None:
    """Why SocketCAN on ``channel`` cannot be used here, or None when it can.

    Parameters
    ----------
    channel : str or None
        Network interface to look for; None checks only the kernel's SocketCAN support.

    Returns
    -------
    str or None
        One line, e.g. "this kernel has no SocketCAN (AF_CAN unsupported)".
    """
    af_can = getattr(socket, "AF_CAN", None)
    if af_can is None:
        return "this platform has no SocketCAN (socket.AF_CAN missing)"
    try:
        socket.socket(af_can, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError as exc:
        return f"this kernel has no SocketCAN (AF_CAN: {exc.strerror or exc})"
    if channel:
        try:
            socket.if_nametoindex(channel)
        except OSError:
            return (f"no network interface {channel} (create it: ip link add dev {channel} "
                    f"type vcan && ip link set up {channel})")
    return None


def socketcan_available(channel: str | None = "vcan0") -> bool:
    """True when SocketCAN works here and ``channel`` exists (see :func:`socketcan_problem`)."""
    return socketcan_problem(channel) is None


def _open_failure(cfg: BusConfig, exc: BaseException) -> str:
    where = f"cannot open CAN bus {cfg.label}"
    if cfg.interface == "socketcan" and isinstance(exc, OSError):
        code = exc.errno
        if code in (errno.EAFNOSUPPORT, errno.EPROTONOSUPPORT):
            return (f"{where}: this kernel has no SocketCAN (AF_CAN unsupported); use "
                    "can_interface: udp_multicast with an interface-local channel such as "
                    "ff11::1, or can_interface: virtual")
        if code == errno.ENODEV:
            return (f"{where}: no network interface {cfg.channel} (create it: ip link add "
                    f"dev {cfg.channel} type vcan && ip link set up {cfg.channel})")
    if cfg.interface == "udp_multicast" and "msgpack" in str(exc):
        return f"{where}: udp_multicast needs the msgpack package ({one_line(exc, with_type=True)})"
    return f"{where}: {one_line(exc, with_type=True)}"


def open_bus(cfg: BusConfig) -> can.BusABC:
    """Open the python-can bus ``cfg`` describes.

    Parameters
    ----------
    cfg : BusConfig

    Returns
    -------
    can.BusABC
        The open bus; the caller shuts it down.

    Raises
    ------
    CanBusError
        One line: the bus, the cause and, where known, the remedy (e.g. socketcan where the
        kernel lacks AF_CAN: use udp_multicast on an ``ff11::`` group, or virtual).
    """
    try:
        return can.Bus(**cfg.bus_kwargs())
    except Exception as exc:  # interfaces raise CanError, OSError, ImportError, ...
        raise CanBusError(_open_failure(cfg, exc)) from exc


def _is_congestion(exc: BaseException) -> bool:
    """A full transmit queue: the frame is lost but the bus is fine."""
    if isinstance(exc, can.CanTimeoutError):
        return True
    code = getattr(exc, "error_code", None)
    if code is None and isinstance(exc, OSError):
        code = exc.errno
    return code in (errno.ENOBUFS, errno.EAGAIN) or "buffer full" in str(exc).lower()


class ResilientBus:
    """A python-can bus that survives errors: lazy open, counted drops, reopen with backoff.

    :meth:`send` and :meth:`recv` never raise for bus trouble.  The bus opens on first use.
    When opening, sending or receiving fails, the bus is shut down, the error is kept in
    :attr:`last_error` (one line) and the bus is reopened on the first :meth:`send` or
    :meth:`recv` after the backoff: ``backoff_initial_s`` after the first failure, doubling
    with every further failure up to ``backoff_max_s``, back to ``backoff_initial_s`` after
    a send or receive that succeeded.  Nothing is queued while the bus is down: frames sent
    then are dropped and counted (``tx_dropped``).  A full transmit queue (``ENOBUFS``,
    python-can's "Transmit buffer full", :class:`can.CanTimeoutError`) drops the frame but
    is no bus failure.

    Thread safety: one thread may :meth:`recv` while another :meth:`send`\\ s (python-can's
    socketcan, virtual and udp_multicast buses allow that); :meth:`close` may be called from
    any thread and ends a waiting :meth:`recv`.  Each counter is written by one side only
    (``tx_*`` by the sender, ``rx_*`` by the receiver); failures and reopens are serialised
    by a lock.

    Parameters
    ----------
    cfg : BusConfig
        The bus to open.
    backoff_initial_s : float
        Wait after the first failure before reopening [s].
    backoff_max_s : float
        Longest wait [s].
    clock : callable
        Monotonic clock [s] of the backoff schedule (receive timeouts use real time).
    log : CanLog, optional
        Every frame sent and received is handed to it
        (:class:`~can_bridge.can_log.CanLog`: a BLF or ASC file).

    Attributes
    ----------
    config : BusConfig
    state : str
        ``"idle"`` (not opened yet), ``"up"``, ``"down"`` (failed, reopen pending) or
        ``"closed"`` (:meth:`close` called).
    last_error : str or None
        The latest failure, one line; kept after recovery.
    error_count : int
        Failures (open, send or receive).
    reopen_count : int
        Successful opens after a failure.
    tx_frames, tx_dropped : int
        Frames sent; frames not sent (bus down, send failed, transmit queue full).
    rx_frames, rx_error_frames : int
        Data/remote frames received; CAN error frames received (counted, not returned).
    """

    def __init__(self, cfg: BusConfig, *, backoff_initial_s: float = 0.1,
                 backoff_max_s: float = 5.0,
                 clock: Callable[[], float] = time.monotonic,
                 log: CanLog | None = None) -> None:
        if not (math.isfinite(backoff_initial_s) and backoff_initial_s >= 0):
            raise UserError(f"backoff_initial_s must be finite and >= 0, got "
                             f"{backoff_initial_s!r}")
        if not (math.isfinite(backoff_max_s) and backoff_max_s >= backoff_initial_s):
            raise UserError(f"backoff_max_s must be finite and >= backoff_initial_s, got "
                             f"{backoff_max_s!r}")
        self.config = cfg
        self.log = log
        self._backoff_initial = float(backoff_initial_s)
        self._backoff_max = float(backoff_max_s)
        self._clock = clock
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._bus: can.BusABC | None = None
        self._generation = 0
        self._backoff = self._backoff_initial
        self._retry_at = -math.inf
        self._failed = False
        self.state = "idle"
        self.last_error: str | None = None
        self.error_count = 0
        self.reopen_count = 0
        self.tx_frames = 0
        self.tx_dropped = 0
        self.rx_frames = 0
        self.rx_error_frames = 0

    # -- state ---------------------------------------------------------------------------
    @property
    def is_up(self) -> bool:
        """True while a bus is open."""
        return self.state == "up"

    @property
    def backoff_s(self) -> float:
        """The wait that the next failure will schedule [s]."""
        return self._backoff

    @property
    def retry_in_s(self) -> float:
        """Seconds until the next reopen attempt may happen (0 when up or due)."""
        if self.state in ("up", "idle"):
            return 0.0
        if self.state == "closed":
            return math.inf
        return max(0.0, self._retry_at - self._clock())

    def __repr__(self) -> str:
        return (f"ResilientBus({self.config.label}, state={self.state}, "
                f"last_error={self.last_error!r})")

    def ensure_open(self) -> bool:
        """Open the bus now if it is not open and no backoff is pending.

        Returns
        -------
        bool
            True when the bus is up.
        """
        return self._acquire()[0] is not None

    def _acquire(self) -> tuple[can.BusABC | None, int]:
        with self._lock:
            if self._bus is not None or self.state == "closed":
                return self._bus, self._generation
            if self._clock() < self._retry_at:
                return None, self._generation
            try:
                bus = open_bus(self.config)
            except CanBusError as exc:
                self._record_failure(str(exc))
                return None, self._generation
            self._bus = bus
            self._generation += 1
            self.state = "up"
            if self._failed:
                self.reopen_count += 1
                _log.info("CAN bus %s reopened", self.config.label)
            return bus, self._generation

    def _record_failure(self, text: str) -> None:
        # with self._lock held
        self.last_error = text
        self.error_count += 1
        self._failed = True
        self.state = "down"
        self._retry_at = self._clock() + self._backoff
        _log.warning("%s; retry in %.3g s", text, self._backoff)
        self._backoff = min(self._backoff_max, 2.0 * self._backoff)

    def _fail(self, generation: int, what: str, exc: BaseException) -> None:
        with self._lock:
            if generation != self._generation or self._bus is None:
                return      # the other thread has handled this bus's failure already
            bus, self._bus = self._bus, None
            self._record_failure(f"CAN bus {self.config.label}: {what} failed: "
                                 f"{one_line(exc, with_type=True)}")
        with contextlib.suppress(Exception):  # already broken; nothing more to do
            bus.shutdown()

    def _succeeded(self) -> None:
        if self._backoff != self._backoff_initial:
            with self._lock:
                self._backoff = self._backoff_initial

    # -- traffic -------------------------------------------------------------------------
    def send(self, msg: can.Message, timeout_s: float | None = None) -> bool:
        """Send one frame, never queueing it.

        Parameters
        ----------
        msg : can.Message
        timeout_s : float, optional
            Passed to the python-can bus: how long to wait for room in the transmit queue
            (None: the interface's default; socketcan then does not wait).

        Returns
        -------
        bool
            True when the bus took the frame; False (counted in ``tx_dropped``) when the bus
            is down or closed, the send failed (the bus then goes down) or the transmit queue
            is full.
        """
        bus, generation = self._acquire()
        if bus is None:
            self.tx_dropped += 1
            return False
        try:
            bus.send(msg, timeout_s)
        except (can.CanError, OSError) as exc:
            self.tx_dropped += 1
            if _is_congestion(exc):
                self.last_error = (f"CAN bus {self.config.label}: transmit queue full: "
                                   f"{one_line(exc, with_type=True)}")
            else:
                self._fail(generation, "send", exc)
            return False
        self._succeeded()
        self.tx_frames += 1
        if self.log is not None:
            self.log.add(msg, received=False)
        return True

    def recv(self, timeout_s: float | None = 0.0) -> can.Message | None:
        """Receive one frame.

        Parameters
        ----------
        timeout_s : float or None
            Longest wait [s]; 0 polls; None waits until a frame arrives or :meth:`close`.
            While the bus is down the wait continues (reopening when the backoff is over).

        Returns
        -------
        can.Message or None
            A data or remote frame; None on timeout, while down or after :meth:`close`.
            Error frames are counted (``rx_error_frames``) and skipped.
        """
        end = math.inf if timeout_s is None else time.monotonic() + max(0.0, timeout_s)
        while True:
            bus, generation = self._acquire()
            remaining = end - time.monotonic()
            if bus is None:
                if self.state == "closed":
                    return None
                wait = min(remaining, self.retry_in_s)
                if wait > 0 and self._closed.wait(wait):
                    return None
                if time.monotonic() >= end:
                    return None
                continue
            try:
                # waits in slices, so that close() from another thread ends the wait on
                # every interface (a virtual bus does not wake up when shut down)
                msg = bus.recv(min(max(0.0, remaining), _RECV_SLICE_S))
            except (can.CanError, OSError, ValueError) as exc:
                # ValueError: select() on a socket another thread has closed
                self._fail(generation, "receive", exc)
                if time.monotonic() >= end:
                    return None
                continue
            self._succeeded()
            if msg is None:
                if time.monotonic() >= end or self._closed.is_set():
                    return None
                continue
            if msg.is_error_frame:
                self.rx_error_frames += 1
                if time.monotonic() >= end:
                    return None
                continue
            self.rx_frames += 1
            if self.log is not None:
                self.log.add(msg, received=True)
            return msg

    def close(self) -> None:
        """Shut the bus down for good; later sends drop, receives return None."""
        with self._lock:
            self.state = "closed"
            self._closed.set()
            bus, self._bus = self._bus, None
            self._generation += 1
        if bus is not None:
            try:
                bus.shutdown()
            except Exception as exc:  # noqa: BLE001 - best effort: the bus is dropped anyway
                _log.debug("shutting down %s: %s", self.config.label, exc)

    def __enter__(self) -> ResilientBus:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()


#: A frame timestamp further than this from the present is not a receive time [s].
STAMP_TOLERANCE_S = 1.0


def receive_time(msg: can.Message, realtime_offset_s: float) -> float:
    """When ``msg`` arrived, on ``time.monotonic``'s clock [s].

    socketcan and udp_multicast stamp a frame in the kernel as it arrives (wall-clock
    time): a process that stalled learns when its frames really came.  ``realtime_offset_s``
    is ``time.time() − time.monotonic()`` (taken once); a frame without such a stamp (or
    with one further than :data:`STAMP_TOLERANCE_S` from now) arrived now.
    """
    now = time.monotonic()
    stamp = float(msg.timestamp or 0.0) - realtime_offset_s
    return stamp if abs(stamp - now) < STAMP_TOLERANCE_S and stamp <= now else now
