"""A MAVLink 2 endpoint over UDP (or any pymavlink byte connection): parse, filter, send.

pymavlink is used for the message definitions, packing and parsing (``common`` dialect, which
both PX4 and ArduPilot speak for every message used here). UDP is handled here rather than by
``mavutil.mavudp`` because a listening ``mavudp`` replies to whoever sent the last datagram: one
stray or hostile packet would steal the vehicle's link. Here the peer is pinned to the first
address that sent a valid HEARTBEAT, and datagrams from elsewhere are counted and dropped.
Malformed bytes never raise: they are counted (``bad_packets``) and skipped.

URLs, as in mavutil: ``udp:HOST:PORT`` and ``udpin:HOST:PORT`` listen, ``udpout:HOST:PORT``
sends first; ``tcp:HOST:PORT`` and serial devices (``/dev/ttyACM0[,BAUD]``) go through mavutil.
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable

from inspect_pipe.errors import InputError

__all__ = ["EndpointStats", "MavlinkEndpoint", "mavlink_available", "require_pymavlink"]


def mavlink_available() -> bool:
    try:
        import pymavlink  # noqa: F401
    except ImportError:
        return False
    return True


def require_pymavlink(where: str = "mavlink") -> Any:
    """The pymavlink ``common`` dialect module, or a one-line error saying how to install it."""
    try:
        from pymavlink.dialects.v20 import common
    except ImportError:
        raise InputError(where, "pymavlink is not installed", "pip install 'inspect-pipe[mavlink]'") from None
    return common


@dataclass
class EndpointStats:
    packets_in: int = 0
    bad_packets: int = 0  # CRC errors, truncated or unknown frames
    foreign_packets: int = 0  # from another address or another MAVLink system
    packets_out: int = 0


class _Sink:
    """File-like object pymavlink's ``MAVLink.send`` writes packed bytes to."""

    def __init__(self, endpoint: "MavlinkEndpoint") -> None:
        self.endpoint = endpoint

    def write(self, buf: bytes) -> None:
        self.endpoint._write(bytes(buf))


class MavlinkEndpoint:
    def __init__(self, url: str, *, system_id: int, component_id: int,
                 accept_heartbeat: Callable[[Any], bool] = lambda m: True) -> None:
        """``accept_heartbeat(msg)``: whether a HEARTBEAT's sender may become the peer."""
        common = require_pymavlink(url)
        self.accept_heartbeat = accept_heartbeat
        self.url = url
        self.common = common
        self.stats = EndpointStats()
        self._lock = threading.Lock()
        self.mav = common.MAVLink(_Sink(self), srcSystem=system_id, srcComponent=component_id)
        self.mav.robust_parsing = True
        self._sock: socket.socket | None = None
        self._conn: Any = None  # mavutil connection for non-UDP URLs
        self.peer: tuple[str, int] | None = None
        self.peer_system: int | None = None  # pinned on the first valid heartbeat
        scheme, _, rest = url.partition(":")
        try:
            if scheme in ("udp", "udpin", "udpout"):
                host, _, port = rest.rpartition(":")
                addr = (host or "127.0.0.1", int(port))
                lowest = 1 if scheme == "udpout" else 0  # listening on port 0: the system picks a free one
                if not lowest <= addr[1] <= 65535:
                    raise ValueError(f"port {addr[1]} is not in {lowest}..65535")
                self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                if scheme == "udpout":
                    self.peer = addr
                    self._sock.bind(("0.0.0.0" if addr[0] not in ("127.0.0.1", "localhost") else "127.0.0.1", 0))
                else:
                    self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                    self._sock.bind(addr)
                self.listening = scheme != "udpout"
            else:
                from pymavlink import mavutil

                try:
                    self._conn = mavutil.mavlink_connection(url, source_system=system_id, source_component=component_id)
                except ModuleNotFoundError as err:
                    if err.name != "serial":
                        raise
                    raise InputError(url, "a serial link needs pyserial, which is not installed",
                                     "pip install 'inspect-pipe[serial]', or give udp:HOST:PORT / tcp:HOST:PORT") from None
                self.listening = False
        except (ValueError, OSError, OverflowError) as err:
            raise InputError(url, f"cannot open the MAVLink connection ({err})",
                             "use udp:HOST:PORT to listen, udpout:HOST:PORT to send, tcp:HOST:PORT or a serial device") from None

    # ------------------------------------------------------------------ I/O
    def _write(self, buf: bytes) -> None:
        try:
            if self._sock is not None:
                if self.peer is None:
                    return  # listening and nobody has spoken yet
                self._sock.sendto(buf, self.peer)
            else:
                self._conn.write(buf)
            self.stats.packets_out += 1
        except OSError:
            pass  # a UDP peer that went away: the loss shows as missing heartbeats

    def send(self, msg: Any) -> None:
        with self._lock:  # several threads send; the sequence number must stay consistent
            self.mav.send(msg)

    def recv(self, timeout_s: float, max_datagrams: int = 64) -> list[Any]:
        """Messages received within ``timeout_s`` (possibly none), filtered and valid: waits for
        the first datagram, then takes whatever else is already queued."""
        out: list[Any] = []
        if self._sock is None:
            data = self._conn.recv(65535) or b""
            if not data:
                time.sleep(min(timeout_s, 0.01))
                return out
            self._parse(data, None, out)
            return out
        self._sock.settimeout(timeout_s)
        for _ in range(max_datagrams):
            try:
                data, addr = self._sock.recvfrom(65535)
            except (socket.timeout, BlockingIOError, OSError):
                break
            self._sock.settimeout(0.0)
            if self.peer is not None and addr != self.peer and not (self.listening and self.peer_system is None):
                self.stats.foreign_packets += 1
                continue
            self._parse(data, addr, out)
        return out

    def _parse(self, data: bytes, addr: tuple[str, int] | None, out: list[Any]) -> None:
        datagram = addr is not None  # a MAVLink frame never spans two UDP datagrams
        try:
            msgs = self.mav.parse_buffer(data) or []
        except Exception:  # pymavlink raises on some malformed frames even when robust
            self.stats.bad_packets += 1
            msgs = []
            datagram = True
        if datagram and self.mav.buf_len() > 0:
            # A truncated frame must not swallow the next datagram's good frames.
            self.stats.bad_packets += 1
            self.mav.buf = bytearray()
            self.mav.buf_index = 0
            self.mav.expected_length = self.common.HEADER_LEN_V1 + 2  # the parser's idle state
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                self.stats.bad_packets += 1
                continue
            if self.peer_system is None and m.get_type() == "HEARTBEAT" and self.accept_heartbeat(m):
                self.peer_system = m.get_srcSystem()
                if self.listening and addr is not None:
                    self.peer = addr
            if self.peer_system is None or m.get_srcSystem() != self.peer_system:
                self.stats.foreign_packets += 1
                continue
            self.stats.packets_in += 1
            out.append(m)

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
        if self._conn is not None:
            self._conn.close()
