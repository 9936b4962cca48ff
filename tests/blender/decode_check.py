"""Runs the Blender add-on's decoder (clients/blender/rigless_live/stream.py; no Blender
needed) on the messages the Rust codec wrote to DIR (messages.bin, one after the other),
then on arbitrary mutations of them and on arbitrary bytes: it must decode or raise
ProtocolError saying why, never anything else. Prints one JSON line: what it decoded,
and the counts.

    python3 decode_check.py DIR CASES

tests/client_decoders.rs runs it.
"""

import importlib.util
import json
import os
import random
import struct
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
spec = importlib.util.spec_from_file_location(
    "stream", os.path.join(ROOT, "clients", "blender", "rigless_live", "stream.py"))
stream = importlib.util.module_from_spec(spec)
spec.loader.exec_module(stream)


def main():
    directory, cases = sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 20000
    data = open(os.path.join(directory, "messages.bin"), "rb").read()
    messages, at = [], 0
    while at < len(data):
        (length,) = struct.unpack_from("<I", data, at + 8)
        messages.append(data[at:at + 12 + length])
        at += 12 + length
    decoded = []
    for m in messages:
        kind, d = stream.decode_message(m)
        if kind == stream.KIND_TOPOLOGY:
            decoded.append({"kind": kind, "character": d["character"], "vertexCount": d["vertex_count"],
                            "triangles": [i for t in d["triangles"] for i in t], "markerNames": d["marker_names"],
                            "jointNames": d["joint_names"], "jointParents": d["joint_parents"],
                            "parts": [[p["name"], p["first_vertex"], p["vertex_count"], p["first_triangle"],
                                       p["triangle_count"]] for p in d["parts"]],
                            "actor": d["actor"], "actorIndex": d["actor_index"], "actorCount": d["actor_count"]})
        elif kind == stream.KIND_FRAME:
            decoded.append({"kind": kind, "frame": d["frame"], "actor": d["actor"], "publishTime": d["publish_time_s"],
                            "receivedTime": d["received_time_s"], "states": list(d["marker_states"]),
                            "vertices": list(d["vertices_m"]), "joints": list(d["joints_m"])})
        else:
            decoded.append({"kind": kind, "reason": d})
    rng = random.Random(0x5EED)
    accepted = refused = 0
    bad = []
    for c in range(cases):
        k = c % 4
        if k == 3:
            b = bytes(rng.randrange(256) for _ in range(rng.randrange(300)))
        else:
            b = bytearray(rng.choice(messages))
            if k == 0:
                for _ in range(1 + rng.randrange(8)):
                    b[rng.randrange(len(b))] = rng.randrange(256)
            elif k == 1:
                pos = rng.randrange(max(1, len(b) - 4))
                value = rng.choice([rng.randrange(1 << 32), 0, 1, 0xFFFFFFFF, 0x7FFFFFFF, len(b)])
                struct.pack_into("<I", b, pos, value)
            else:
                b = b[:rng.randrange(len(b))] if rng.random() < 0.5 else b + bytes(1 + rng.randrange(16))
            b = bytes(b)
        try:
            stream.decode_message(b)
            accepted += 1
        except stream.ProtocolError:
            refused += 1
        except Exception as e:  # noqa: BLE001 (what the check is for)
            bad.append(f"{type(e).__name__}: {e}")
    print(json.dumps({"decoded": decoded, "cases": cases, "accepted": accepted, "refused": refused,
                      "bad": bad[:5], "bad_count": len(bad)}))


if __name__ == "__main__":
    main()
