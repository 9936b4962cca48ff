#!/usr/bin/env python3
"""Reference client for the rigless vertex stream, versions 1 to 4 (protocols/vertex-stream.md).

Standard library only. Connects over TCP, reads the topology and then frames, and prints
what it got: one JSON line per frame with --frames-json, and a JSON summary at the end.

    python3 vertex_stream_client.py 127.0.0.1:7878 --frames 120
"""

import argparse
import json
import math
import socket
import struct
import sys

MAGIC = b"RGLS"
VERSIONS = (1, 2, 3, 4)
HEADER = struct.Struct("<4sHHI")
MAX_PAYLOAD_LEN = 64 << 20
KIND_TOPOLOGY, KIND_FRAME, KIND_GOODBYE = 1, 2, 3
FILL_STATES = ["measured", "predicted", "rigid_filled", "held"]
STOP_CODES = ["converged", "iteration_cap", "deadline"]


class ProtocolError(Exception):
    pass


class Reader:
    """A cursor over one payload; every read is bounds-checked."""

    def __init__(self, data, kind):
        self.data, self.at, self.kind = data, 0, kind

    def take(self, n):
        if n < 0 or self.at + n > len(self.data):
            raise ProtocolError(f"{self.kind} payload truncated at byte {self.at}")
        b = self.data[self.at:self.at + n]
        self.at += n
        return b

    def unpack(self, fmt):
        s = struct.Struct("<" + fmt)
        return s.unpack(self.take(s.size))

    def string(self):
        (n,) = self.unpack("H")
        return self.take(n).decode("utf-8")

    def count(self, min_item):
        (n,) = self.unpack("I")
        if n * min_item > len(self.data) - self.at:
            raise ProtocolError(f"{self.kind} count {n} larger than the payload")
        return n

    def end(self):
        if self.at != len(self.data):
            raise ProtocolError(f"{self.kind} payload has {len(self.data) - self.at} trailing bytes")


def decode_topology(p, version):
    r = Reader(p, "topology")
    t = {"character": r.string(), "rate_hz": r.unpack("f")[0], "length_unit": r.string(),
         "up_axis": r.string(), "handedness": r.string(), "vertex_count": r.unpack("I")[0]}
    nt = r.count(12)
    tris = r.unpack(f"{3 * nt}I") if nt else ()
    t["triangles"] = [tris[i:i + 3] for i in range(0, len(tris), 3)]
    t["marker_names"] = [r.string() for _ in range(r.count(2))]
    joints = []
    for _ in range(r.count(6)):
        name = r.string()
        (parent,) = r.unpack("i")
        joints.append((name, parent))
    t["joint_names"] = [j[0] for j in joints]
    t["joint_parents"] = [j[1] for j in joints]
    t["parts"] = []
    if version >= 2:
        for _ in range(r.count(18)):
            name = r.string()
            first_v, nv, first_t, nt_p = r.unpack("4I")
            if first_v + nv > t["vertex_count"] or first_t + nt_p > nt:
                raise ProtocolError(f"part {name!r} has a range outside the mesh")
            t["parts"].append({"name": name, "first_vertex": first_v, "vertex_count": nv,
                               "first_triangle": first_t, "triangle_count": nt_p})
    # Version 4: the actor this topology is for; before, one actor named after its character.
    t["actor"], t["actor_index"], t["actor_count"] = t["character"], 0, 1
    if version >= 4:
        t["actor_index"], t["actor_count"] = r.unpack("BB")
        if t["actor_index"] >= t["actor_count"]:
            raise ProtocolError(f"actor index {t['actor_index']} not below the actor count {t['actor_count']}")
        t["actor"] = r.string()
    r.end()
    return t


def decode_frame(p, version):
    r = Reader(p, "frame")
    frame, source_time_s, publish_time_s = r.unpack("Qdd")
    iterations, stop, actor = r.unpack("HBB")
    if version < 4:
        actor = 0  # reserved (zero) before version 4
    names = ["solve_ms", "gc_ms", "rrms", "bone_length_error", "joint_limit_violation_deg",
             "marker_residual_rms_mm", "marker_residual_max_mm"]
    status = dict(zip(names, r.unpack("7f")))
    status["iterations"] = iterations
    if stop >= len(STOP_CODES):
        raise ProtocolError(f"unknown stop code {stop}")
    status["stop"] = STOP_CODES[stop]
    nm = r.count(13)
    codes = r.take(nm)
    if any(c >= len(FILL_STATES) for c in codes):
        raise ProtocolError("unknown fill state")
    r.take((4 - nm % 4) % 4)
    markers = r.unpack(f"{3 * nm}f") if nm else ()
    nv = r.count(12)
    vertices = r.unpack(f"{3 * nv}f") if nv else ()
    received_time_s, joints = 0.0, ()
    if version >= 3:
        (received_time_s,) = r.unpack("d")
        nj = r.count(12)
        joints = r.unpack(f"{3 * nj}f") if nj else ()
    r.end()
    return {"frame": frame, "actor": actor, "source_time_s": source_time_s, "publish_time_s": publish_time_s,
            "received_time_s": received_time_s,
            "status": status, "marker_states": [FILL_STATES[c] for c in codes],
            "markers_m": [markers[i:i + 3] for i in range(0, len(markers), 3)],
            "vertices_m": vertices,
            "joints_m": [joints[i:i + 3] for i in range(0, len(joints), 3)]}


def read_exact(sock, n):
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)


def read_message(sock):
    """Returns (version, kind, payload), or None when the server closed the connection."""
    h = read_exact(sock, HEADER.size)
    if h is None:
        return None
    magic, version, kind, length = HEADER.unpack(h)
    if magic != MAGIC:
        raise ProtocolError(f"bad magic {magic!r}")
    if version not in VERSIONS:
        raise ProtocolError(f"unsupported version {version}")
    if length > MAX_PAYLOAD_LEN:
        raise ProtocolError(f"payload of {length} bytes exceeds the limit")
    p = read_exact(sock, length)
    if p is None:
        raise ProtocolError("connection closed inside a message")
    return version, kind, p


def new_summary():
    return {"topology": None, "actors": [], "frames": 0, "first_frame": None, "last_frame": None,
            "frame_numbers_increasing": True, "skipped": 0, "goodbye": None,
            "all_finite": True, "bbox_min": [math.inf] * 3, "bbox_max": [-math.inf] * 3,
            "fill_counts": {s: 0 for s in FILL_STATES}, "stops": {s: 0 for s in STOP_CODES},
            "vertex_count_matches": True, "marker_count_matches": True,
            "joint_count_matches": True}


def on_topology(summary, topologies, t):
    """Keeps actor t's topology; the summary's `topology` is actor 0's."""
    if t["actor_index"] in topologies:
        raise ProtocolError(f"a second topology for actor {t['actor_index']}")
    topologies[t["actor_index"]] = t
    brief = {k: (len(v) if isinstance(v, list) else v) for k, v in t.items()}
    brief["marker_names"] = t["marker_names"]
    brief["part_names"] = [q["name"] for q in t["parts"]]
    if t["actor_index"] == 0:
        summary["topology"] = brief
    summary["actors"].append({"name": t["actor"], "index": t["actor_index"],
                              "character": t["character"], "vertex_count": t["vertex_count"],
                              "frames": 0, "first_frame": None, "last_frame": None,
                              "bbox_min": [math.inf] * 3, "bbox_max": [-math.inf] * 3})
    summary["actors"].sort(key=lambda a: a["index"])


def on_frame(summary, topologies, f, version):
    """Checks frame f against its actor's topology and adds it to the summary."""
    t = topologies.get(f["actor"])
    if t is None:
        raise ProtocolError(f"a frame of actor {f['actor']} before its topology")
    actor = next(a for a in summary["actors"] if a["index"] == f["actor"])
    last = actor["last_frame"]
    if last is not None:
        if f["frame"] <= last:
            summary["frame_numbers_increasing"] = False
        else:
            summary["skipped"] += f["frame"] - last - 1
    for d in (summary, actor):
        d["first_frame"] = f["frame"] if d["first_frame"] is None else d["first_frame"]
        d["last_frame"] = max(f["frame"], d["last_frame"] or 0)
        d["frames"] += 1
    v = f["vertices_m"]
    if len(v) != 3 * t["vertex_count"]:
        summary["vertex_count_matches"] = False
    if version >= 3 and len(f["joints_m"]) != len(t["joint_names"]):
        summary["joint_count_matches"] = False
    if len(f["marker_states"]) != len(t["marker_names"]):
        summary["marker_count_matches"] = False
    if not all(math.isfinite(x) for x in v):
        summary["all_finite"] = False
    for a in range(3):
        axis = v[a::3]
        if axis:
            for d in (summary, actor):
                d["bbox_min"][a] = min(d["bbox_min"][a], min(axis))
                d["bbox_max"][a] = max(d["bbox_max"][a], max(axis))
    for st in f["marker_states"]:
        summary["fill_counts"][st] += 1
    summary["stops"][f["status"]["stop"]] += 1


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("address", help="HOST:PORT of the vertex stream")
    ap.add_argument("--frames", type=int, default=0,
                    help="stop after this many frames, over all actors (0: until the server says goodbye)")
    ap.add_argument("--timeout", type=float, default=10.0, help="socket timeout, seconds")
    ap.add_argument("--frames-json", action="store_true", help="print every frame's header as JSON")
    args = ap.parse_args()
    host, port = args.address.rsplit(":", 1)
    sock = socket.create_connection((host, int(port)), timeout=args.timeout)
    summary, topologies = new_summary(), {}
    while True:
        m = read_message(sock)
        if m is None:
            break
        version, kind, p = m
        if kind == KIND_TOPOLOGY:
            on_topology(summary, topologies, decode_topology(p, version))
        elif kind == KIND_FRAME:
            f = decode_frame(p, version)
            on_frame(summary, topologies, f, version)
            if args.frames_json:
                print(json.dumps({k: f[k] for k in ("frame", "actor", "source_time_s", "publish_time_s",
                                                    "received_time_s", "status", "marker_states")}))
            if args.frames and summary["frames"] >= args.frames:
                break
        elif kind == KIND_GOODBYE:
            summary["goodbye"] = Reader(p, "goodbye").string()
            break
        else:
            raise ProtocolError(f"unknown message kind {kind}")
    sock.close()
    print(json.dumps({"summary": summary}))


if __name__ == "__main__":
    try:
        main()
    except (ProtocolError, OSError) as e:
        print(f"vertex_stream_client: {e}", file=sys.stderr)
        sys.exit(1)
