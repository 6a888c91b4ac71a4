"""Reads one render frame of a running scalpel station with the iceoryx2 Python wheel,
using only docs/PROTOCOL.md, and prints what it found as one JSON object.

    python read_frame.py STATION [TIMEOUT_S]
"""

import ctypes
import json
import struct
import sys
import time

import iceoryx2 as iox2


class FrameHeader(ctypes.Structure):
    """docs/PROTOCOL.md, "Render frames": the user header, 120 bytes, alignment 8."""

    _fields_ = [
        ("layout_version", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("frame", ctypes.c_uint64),
        ("sim_tick", ctypes.c_uint64),
        ("server_time_ns", ctypes.c_uint64),
        ("pose_seq", ctypes.c_uint64),
        ("pose_received_ns", ctypes.c_uint64),
        ("n_vertices", ctypes.c_uint32),
        ("n_triangles", ctypes.c_uint32),
        ("positions_offset", ctypes.c_uint32),
        ("normals_offset", ctypes.c_uint32),
        ("triangles_offset", ctypes.c_uint32),
        ("materials_offset", ctypes.c_uint32),
        ("tool_tip_m", ctypes.c_float * 3),
        ("blade_length_m", ctypes.c_float),
        ("tool_orientation_xyzw", ctypes.c_float * 4),
        ("force_n", ctypes.c_float * 3),
        ("cut_length_mm", ctypes.c_float),
    ]

    @staticmethod
    def type_name() -> str:
        return "ScalpelFrameHeader"


def main() -> int:
    station = sys.argv[1]
    timeout_s = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0
    assert ctypes.sizeof(FrameHeader) == 120 and ctypes.alignment(FrameHeader) == 8

    iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
    node = (
        iox2.NodeBuilder.new()
        .name(iox2.NodeName.new(f"python-reader.{station}"))
        .create(iox2.ServiceType.Ipc)
    )
    # The station's server makes its services; a renderer only opens them (retrying while
    # the server starts).
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            service = (
                node.service_builder(iox2.ServiceName.new(f"scalpel/{station}/render/frames"))
                .publish_subscribe(iox2.Slice[ctypes.c_uint8])
                .user_header(FrameHeader)
                .max_publishers(1)
                .max_subscribers(8)
                .subscriber_max_buffer_size(2)
                .history_size(1)
                .open()
            )
            break
        except Exception as e:  # noqa: BLE001 (iceoryx2's open errors have no common base)
            if time.monotonic() > deadline:
                print(json.dumps({"error": f"station {station} not running: {e}"}))
                return 1
            time.sleep(0.1)
    subscriber = service.subscriber_builder().create()

    while time.monotonic() < deadline:
        sample = subscriber.receive()
        if sample is None:
            time.sleep(0.01)
            continue
        h = sample.user_header().contents
        data = bytes(sample.payload().as_memory_view())
        if h.layout_version != 2:
            print(json.dumps({"error": f"layout version {h.layout_version}"}))
            return 1
        nv, nt = h.n_vertices, h.n_triangles
        positions = struct.unpack_from(f"<{3 * nv}f", data, h.positions_offset)
        normals = struct.unpack_from(f"<{3 * nv}f", data, h.normals_offset)
        triangles = struct.unpack_from(f"<{3 * nt}I", data, h.triangles_offset)
        materials = data[h.materials_offset : h.materials_offset + nt]
        xs, ys, zs = positions[0::3], positions[1::3], positions[2::3]
        unit = [
            abs(normals[3 * i] ** 2 + normals[3 * i + 1] ** 2 + normals[3 * i + 2] ** 2 - 1.0) < 1e-3
            for i in range(nv)
        ]
        print(
            json.dumps(
                {
                    "frame": h.frame,
                    "sim_tick": h.sim_tick,
                    "n_vertices": nv,
                    "n_triangles": nt,
                    "payload_bytes": len(data),
                    "bbox_mm": [
                        [1e3 * min(xs), 1e3 * min(ys), 1e3 * min(zs)],
                        [1e3 * max(xs), 1e3 * max(ys), 1e3 * max(zs)],
                    ],
                    "max_index": max(triangles),
                    "unit_normals": all(unit),
                    "wound_triangles": sum(1 for m in materials if m == 1),
                    "tool_present": bool(h.flags & 1),
                    "force_n": list(h.force_n),
                }
            )
        )
        return 0
    print(json.dumps({"error": f"no frame from station {station} in {timeout_s} s"}))
    return 1


if __name__ == "__main__":
    sys.exit(main())
