"""The rigless vertex stream for the Blender add-on, without Blender: the decoder
(protocols/vertex-stream.md, versions 1 to 4), a receiver thread that keeps only the
newest frame (and every frame while recording), and a PC2 point-cache writer.

Pure Python (standard library): the add-on's Blender side lives in __init__.py. The
decoder is deliberately separate from protocols/vertex_stream_client.py: the add-on
installs on its own, as one folder, and its test checks each decoder against the other.
"""

import array
import socket
import struct
import sys
import threading

MAGIC = b"RGLS"
VERSIONS = (1, 2, 3, 4)
KIND_TOPOLOGY, KIND_FRAME, KIND_GOODBYE = 1, 2, 3
HEADER = struct.Struct("<4sHHI")
MAX_PAYLOAD_LEN = 64 << 20


class ProtocolError(Exception):
    pass


class Reader:
    """A bounds-checked cursor over one payload."""

    def __init__(self, data, kind):
        self.data, self.at, self.kind = data, 0, kind

    def take(self, n):
        if n < 0 or len(self.data) - self.at < n:
            raise ProtocolError(f"{self.kind}: truncated at byte {self.at}")
        s = self.data[self.at:self.at + n]
        self.at += n
        return s

    def unpack(self, fmt):
        st = struct.Struct("<" + fmt)
        return st.unpack(self.take(st.size))

    def string(self):
        (n,) = self.unpack("H")
        try:
            return bytes(self.take(n)).decode("utf-8")
        except UnicodeDecodeError as e:
            raise ProtocolError(f"{self.kind}: string is not UTF-8") from e

    def count(self, min_item):
        (n,) = self.unpack("I")
        if n * min_item > len(self.data) - self.at:
            raise ProtocolError(f"{self.kind}: count {n} larger than the payload")
        return n

    def floats(self, n):
        """`n` little-endian f32 as an array('f')."""
        a = array.array("f")
        a.frombytes(bytes(self.take(4 * n)))
        if sys.byteorder != "little":
            a.byteswap()
        return a

    def end(self):
        if self.at != len(self.data):
            raise ProtocolError(f"{self.kind}: trailing bytes at {self.at}")


def decode_topology(p, version):
    r = Reader(p, "topology")
    t = {"character": r.string()}
    (t["rate_hz"],) = r.unpack("f")
    t["length_unit"], t["up_axis"], t["handedness"] = r.string(), r.string(), r.string()
    (t["vertex_count"],) = r.unpack("I")
    nt = r.count(12)
    tris = r.unpack(f"{3 * nt}I") if nt else ()
    if any(i >= t["vertex_count"] for i in tris):
        raise ProtocolError("topology: a triangle index is past the vertices")
    t["triangles"] = [tris[i:i + 3] for i in range(0, len(tris), 3)]
    nm = r.count(2)
    t["marker_names"] = [r.string() for _ in range(nm)]
    nj = r.count(6)
    joints = [(r.string(), r.unpack("i")[0]) for _ in range(nj)]
    t["joint_names"] = [j[0] for j in joints]
    t["joint_parents"] = [j[1] for j in joints]
    t["parts"] = []
    if version >= 2:
        for _ in range(r.count(18)):
            name = r.string()
            fv, nv, ft, ntp = r.unpack("4I")
            if fv + nv > t["vertex_count"] or ft + ntp > nt:
                raise ProtocolError(f"topology: part {name!r} runs past the mesh")
            t["parts"].append({"name": name, "first_vertex": fv, "vertex_count": nv,
                               "first_triangle": ft, "triangle_count": ntp})
    # Version 4: the actor this topology is for; before, one actor named after its character.
    t["actor"], t["actor_index"], t["actor_count"] = t["character"], 0, 1
    if version >= 4:
        t["actor_index"], t["actor_count"] = r.unpack("BB")
        if t["actor_index"] >= t["actor_count"]:
            raise ProtocolError(f"topology: actor index {t['actor_index']} not below the count {t['actor_count']}")
        t["actor"] = r.string()
    r.end()
    return t


def decode_frame(p, version):
    r = Reader(p, "frame")
    f = {}
    f["frame"], f["source_time_s"], f["publish_time_s"] = r.unpack("Qdd")
    f["iterations"], f["stop"], f["actor"] = r.unpack("HBB")
    if version < 4:
        f["actor"] = 0  # reserved (zero) before version 4
    (f["solve_ms"], f["gc_ms"], f["rrms"], f["bone_length_error"], f["joint_limit_violation_deg"],
     f["marker_residual_rms_mm"], f["marker_residual_max_mm"]) = r.unpack("7f")
    nm = r.count(13)
    f["marker_states"] = bytes(r.take(nm))
    if any(c > 3 for c in f["marker_states"]):
        raise ProtocolError("frame: unknown marker state")
    r.take((4 - nm % 4) % 4)
    f["markers_m"] = r.floats(3 * nm)
    nv = r.count(12)
    f["vertices_m"] = r.floats(3 * nv)
    f["received_time_s"], f["joints_m"] = 0.0, array.array("f")
    if version >= 3:
        (f["received_time_s"],) = r.unpack("d")
        f["joints_m"] = r.floats(3 * r.count(12))
    r.end()
    return f


def decode_message(data):
    """One whole message (bytes holding exactly one) to (kind, decoded): a topology or a
    frame dict, a goodbye's reason, or None for a kind this add-on does not know."""
    if len(data) < HEADER.size:
        raise ProtocolError("message shorter than its header")
    magic, version, kind, length = HEADER.unpack(data[:HEADER.size])
    if magic != MAGIC or version not in VERSIONS:
        raise ProtocolError(f"bad magic {magic!r} or version {version}")
    if length > MAX_PAYLOAD_LEN or HEADER.size + length != len(data):
        raise ProtocolError(f"payload length {length} for a message of {len(data)} bytes")
    p = data[HEADER.size:]
    if kind == KIND_TOPOLOGY:
        return kind, decode_topology(p, version)
    if kind == KIND_FRAME:
        return kind, decode_frame(p, version)
    if kind == KIND_GOODBYE:
        r = Reader(p, "goodbye")
        reason = r.string()
        r.end()
        return kind, reason
    return kind, None


def read_exact(sock, n):
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(n - len(buf))
        if not chunk:
            return None
        buf += chunk
    return bytes(buf)


def read_message(sock):
    """(version, kind, payload), or None when the server closed the connection."""
    h = read_exact(sock, HEADER.size)
    if h is None:
        return None
    magic, version, kind, length = HEADER.unpack(h)
    if magic != MAGIC:
        raise ProtocolError(f"bad magic {magic!r}: is this a rigless vertex stream (TCP port)?")
    if version not in VERSIONS:
        raise ProtocolError(f"unsupported version {version} (this add-on reads 1 to 4)")
    if length > MAX_PAYLOAD_LEN:
        raise ProtocolError(f"payload of {length} bytes exceeds the limit")
    p = read_exact(sock, length)
    if p is None:
        raise ProtocolError("connection closed inside a message")
    return version, kind, p


class Receiver(threading.Thread):
    """Reads the stream on its own thread. The Blender side takes `newest()` on its
    timer: frames that arrive faster than it applies them are dropped. While
    `recording` is a list, every frame is appended to it as (frame number, vertices).

    A stream of several actors (version 4) carries a topology per actor and frames
    tagged with the actor's index: the receiver follows the actor named `actor` (the
    first when empty) and ignores the others; a name the stream lacks is an error naming
    the actors it has."""

    def __init__(self, host, port, timeout_s=5.0, actor=""):
        super().__init__(name="rigless-stream", daemon=True)
        self.host, self.port, self.timeout_s, self.actor = host, port, timeout_s, actor
        self.lock = threading.Lock()
        # Every actor's topology by index, and the index followed (None: not yet known).
        self.topologies, self.index = {}, None
        self.topology = None
        self.topology_serial = 0
        self.frame = None
        self.frames_received = 0
        self.error = None
        self.goodbye = None
        self.recording = None
        self.closed = threading.Event()
        self.sock = None

    def run(self):
        try:
            self.sock = socket.create_connection((self.host, self.port), timeout=self.timeout_s)
            self.sock.settimeout(None)
            while not self.closed.is_set():
                m = read_message(self.sock)
                if m is None:
                    break
                version, kind, p = m
                if kind == KIND_TOPOLOGY:
                    self._on_topology(decode_topology(p, version))
                elif kind == KIND_FRAME:
                    f = decode_frame(p, version)
                    if self.index is None or f["actor"] != self.index:
                        continue
                    with self.lock:
                        t = self.topology
                        if t is None or len(f["vertices_m"]) != 3 * t["vertex_count"]:
                            raise ProtocolError("a frame before its topology, or of another vertex count")
                        self.frame = f
                        self.frames_received += 1
                        if self.recording is not None:
                            self.recording.append((f["frame"], f["vertices_m"]))
                elif kind == KIND_GOODBYE:
                    self.goodbye = Reader(p, "goodbye").string()
                    break
        except (OSError, ProtocolError) as e:
            if not self.closed.is_set():
                self.error = str(e)
        finally:
            self.closed.set()
            if self.sock is not None:
                self.sock.close()

    def _on_topology(self, t):
        """Keeps actor t's topology; follows it when it is the one asked for. Once every
        actor's topology came and none is, that is an error."""
        self.topologies[t["actor_index"]] = t
        if t["actor"] == self.actor or (not self.actor and t["actor_index"] == 0):
            self.index = t["actor_index"]
            with self.lock:
                self.topology, self.frame = t, None
                self.topology_serial += 1
        elif self.index is None and len(self.topologies) >= t["actor_count"]:
            names = ", ".join(self.topologies[i]["actor"] for i in sorted(self.topologies))
            raise ProtocolError(f"no actor {self.actor!r} in this stream (it has {names})")

    def newest(self):
        """(topology serial, topology, newest frame)."""
        with self.lock:
            return self.topology_serial, self.topology, self.frame

    def start_recording(self):
        with self.lock:
            self.recording = []

    def stop_recording(self):
        """The frames recorded, in order: [(frame number, vertices)]."""
        with self.lock:
            frames, self.recording = self.recording or [], None
        return frames

    def close(self):
        self.closed.set()
        if self.sock is not None:
            try:
                self.sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass


def fill_gaps(frames):
    """One sample per frame number from the first to the last: a frame the reader did not
    get (the server skips frames for a slow reader) repeats the one before it, so that the
    samples stay at the stream's rate."""
    out = []
    for i, (n, v) in enumerate(frames):
        if i > 0:
            gap = n - frames[i - 1][0] - 1
            out.extend([frames[i - 1][1]] * max(gap, 0))
        out.append(v)
    return out


def write_pc2(path, samples, points):
    """Writes `samples` (each an array('f') of 3 × `points` floats) as a PC2 point cache:
    start frame 0, one sample per frame (protocols/pc2.md)."""
    with open(path, "wb") as f:
        f.write(b"POINTCACHE2\0")
        f.write(struct.pack("<iiffi", 1, points, 0.0, 1.0, len(samples)))
        for s in samples:
            if len(s) != 3 * points:
                raise ValueError(f"a sample of {len(s) // 3} points in a cache of {points}")
            a = array.array("f", s)
            if sys.byteorder != "little":
                a.byteswap()
            f.write(a.tobytes())
