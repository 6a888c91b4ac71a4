"""A third-party QUIC client (aioquic) observing a scalpel station, written from
docs/PROTOCOL.md ("Remote clients") alone: mutual TLS with a lab certificate, ALPN
scalpel/1, Hello on the control stream, Subscribe, then one Metrics message from the
telemetry stream and one keyframe from a frame stream, decoded by hand. Prints one JSON
object.

    python quic_observer.py HOST PORT CERTS_DIR NAME [TIMEOUT_S]
"""

import asyncio
import json
import struct
import sys

from aioquic.asyncio import connect
from aioquic.asyncio.protocol import QuicConnectionProtocol
from aioquic.quic.configuration import QuicConfiguration
from aioquic.quic.events import StreamDataReceived


class Reader:
    """bincode 2 standard configuration: varint integers, little-endian floats."""

    def __init__(self, data: bytes):
        self.data = data
        self.at = 0

    def take(self, n: int) -> bytes:
        chunk = self.data[self.at : self.at + n]
        if len(chunk) != n:
            raise ValueError("message ends early")
        self.at += n
        return chunk

    def u(self) -> int:
        b = self.take(1)[0]
        if b < 251:
            return b
        size = {251: 2, 252: 4, 253: 8}[b]
        return int.from_bytes(self.take(size), "little")

    def i(self) -> int:
        z = self.u()
        return (z >> 1) ^ -(z & 1)

    def f32(self) -> float:
        return struct.unpack("<f", self.take(4))[0]

    def f64(self) -> float:
        return struct.unpack("<d", self.take(8))[0]

    def boolean(self) -> bool:
        return self.take(1)[0] == 1

    def byte(self) -> int:
        return self.take(1)[0]

    def string(self) -> str:
        return self.take(self.u()).decode()


def varint(n: int) -> bytes:
    if n < 251:
        return bytes([n])
    for tag, size in ((251, 2), (252, 4), (253, 8)):
        if n < 1 << (8 * size):
            return bytes([tag]) + n.to_bytes(size, "little")
    raise ValueError(n)


def frame(payload: bytes) -> bytes:
    return len(payload).to_bytes(4, "little") + payload


def hello(name: str) -> bytes:
    # ClientMessage::Hello { protocol_version: 3, client }
    return frame(varint(0) + varint(3) + varint(len(name)) + name.encode())


def subscribe(hz: float) -> bytes:
    # ClientMessage::Subscribe { frame_hz }
    return frame(varint(1) + struct.pack("<f", hz))


def decode_server(payload: bytes) -> dict:
    r = Reader(payload)
    kind = r.u()
    if kind == 0:
        out = {
            "welcome": {
                "protocol_version": r.u(),
                "station": r.string(),
                "scene": r.string(),
                "role": ["Observer", "Instructor"][r.u()],
                "identity": r.string(),
            }
        }
    elif kind == 1:
        out = {"refused": r.string()}
    elif kind == 4:
        out = {
            "metrics": {
                "sim_tick": r.u(),
                "station_tick": r.u(),
                "uptime_s": r.f64(),
                "haptic_rate_hz": r.f32(),
                "jitter_p99_ms": r.f32(),
                "deadline_misses": r.u(),
                "force_n": r.f32(),
                "faded": r.boolean(),
                "cut_length_mm": r.f32(),
                "active_points": r.u(),
                "device_connected": r.boolean(),
            }
        }
    elif kind == 5:
        out = {
            "event": {
                "sim_tick": r.u(),
                "uptime_s": r.f64(),
                "kind": r.u(),
                "detail": r.string(),
            }
        }
    elif kind == 6:
        number, keyframe, sim_tick, server_time_ns = r.u(), r.u(), r.u(), r.u()
        triangles, materials = None, None
        if r.byte() == 1:
            triangles = [(r.u(), r.u(), r.u()) for _ in range(r.u())]
            materials = [r.byte() for _ in range(r.u())]
        origin = [r.f32(), r.f32(), r.f32()]
        step = r.f32()
        codes = [(r.i(), r.i(), r.i()) for _ in range(r.u())]
        tool = None
        if r.byte() == 1:
            tool = {
                "tip_m": [r.f32() for _ in range(3)],
                "orientation_xyzw": [r.f32() for _ in range(4)],
                "force_n": [r.f32() for _ in range(3)],
            }
        positions = None
        if triangles is not None:
            positions = [[origin[c] + step * (q[c] + 32768) for c in range(3)] for q in codes]
        out = {
            "frame": {
                "frame": number,
                "keyframe": keyframe,
                "sim_tick": sim_tick,
                "triangles": None if triangles is None else len(triangles),
                "wound_triangles": None if materials is None else sum(1 for m in materials if m == 1),
                "vertices": len(codes),
                "max_index": None if triangles is None else max(max(t) for t in triangles),
                "bbox_mm": None
                if positions is None
                else [
                    [1e3 * min(p[c] for p in positions) for c in range(3)],
                    [1e3 * max(p[c] for p in positions) for c in range(3)],
                ],
                "tool": tool is not None,
            }
        }
    else:
        out = {"other": kind}
    if r.at != len(payload):
        raise ValueError(f"{len(payload) - r.at} bytes after message kind {kind}")
    return out


class Observer(QuicConnectionProtocol):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.buffers: dict[int, bytes] = {}
        self.found: dict[str, dict] = {}
        self.done = asyncio.Event()

    def quic_event_received(self, event) -> None:
        if not isinstance(event, StreamDataReceived):
            return
        buf = self.buffers.get(event.stream_id, b"") + event.data
        while len(buf) >= 4:
            n = int.from_bytes(buf[:4], "little")
            if len(buf) < 4 + n:
                break
            message = decode_server(buf[4 : 4 + n])
            buf = buf[4 + n :]
            for key, value in message.items():
                # The first keyframe, the first metrics, the welcome.
                if key == "frame" and value["triangles"] is None:
                    continue
                self.found.setdefault(key, value)
        self.buffers[event.stream_id] = buf
        if all(k in self.found for k in ("welcome", "metrics", "frame")) or "refused" in self.found:
            self.done.set()


async def main() -> int:
    host, port, certs, name = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
    timeout = float(sys.argv[5]) if len(sys.argv) > 5 else 20.0
    configuration = QuicConfiguration(is_client=True, alpn_protocols=["scalpel/1"], server_name="localhost")
    configuration.load_verify_locations(f"{certs}/ca.pem")
    configuration.load_cert_chain(f"{certs}/{name}.pem", f"{certs}/{name}.key")
    async with connect(host, port, configuration=configuration, create_protocol=Observer) as client:
        stream = client._quic.get_next_available_stream_id()
        client._quic.send_stream_data(stream, hello("aioquic") + subscribe(30.0))
        client.transmit()
        try:
            await asyncio.wait_for(client.done.wait(), timeout)
        except asyncio.TimeoutError:
            print(json.dumps({"error": f"timed out, found {sorted(client.found)}"}))
            return 1
        print(json.dumps(client.found))
    return 0


if __name__ == "__main__":
    sys.exit(asyncio.run(main()))
