"""Drives the Blender add-on (clients/blender/rigless_live) in Blender as a Python module
(`bpy` from PyPI) against a running `rigless demo`, and checks it: 100 applied frames
equal, float for float, the stream's vertices for the same frame numbers (read by the
reference client's decoder on a socket of its own) in Blender's axes; a recording
writes a PC2 cache of one sample per stream frame that a Mesh Cache modifier plays back
on the timeline; a mesh of another vertex count is refused with a message; on the
two-actor demo, the actor named is followed (its frames, not the other's) and a name the
stream lacks is refused, naming the actors it has. Prints one JSON line of
measurements; exits 1 on a failed check.

    python3 check_addon.py RIGLESS_BINARY OUT_DIR

tests/blender_addon.rs runs it.
"""

import json
import os
import re
import socket
import struct
import subprocess
import sys
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "clients", "blender"))
sys.path.insert(0, os.path.join(ROOT, "protocols"))

import vertex_stream_client as ref  # noqa: E402  (the reference client's decoder)
import bpy  # noqa: E402
import mathutils  # noqa: E402  (Blender's vectors)
import numpy as np  # noqa: E402
import rigless_live  # noqa: E402

# Longest wait for anything the add-on or the daemon should do, seconds.
WAIT_S = 60.0


def free_port():
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def start_demo(binary, port, cast=("--character", "hand")):
    p = subprocess.Popen([binary, "demo", *cast, "--loop", "--seconds", "120",
                          "--stream", f"127.0.0.1:{port}", "--viewer", "off", "--rerun", "off"],
                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    deadline = time.time() + WAIT_S
    for line in p.stdout:
        if re.match(r"vertex stream listening on tcp://", line):
            threading.Thread(target=lambda: [None for _ in p.stdout], daemon=True).start()
            return p
        if time.time() > deadline:
            break
    p.kill()
    raise RuntimeError("the demo printed no stream address")


class Reference(threading.Thread):
    """The stream's frames by actor and number, read with the reference client's
    decoder."""

    def __init__(self, port):
        super().__init__(daemon=True)
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=WAIT_S)
        self.frames, self.lock = {}, threading.Lock()

    def run(self):
        try:
            while True:
                m = ref.read_message(self.sock)
                if m is None:
                    return
                version, kind, p = m
                if kind == ref.KIND_FRAME:
                    f = ref.decode_frame(p, version)
                    with self.lock:
                        key = (f["actor"], f["frame"])
                        self.frames[key] = np.array(f["vertices_m"], dtype=np.float32)
                        if len(self.frames) > 4000:
                            self.frames.pop(min(self.frames))
        except OSError:
            return

    def get(self, n, actor=0):
        with self.lock:
            return self.frames.get((actor, n))


def check(cond, what):
    if not cond:
        raise AssertionError(what)


def export(binary, take, out):
    """`rigless replay TAKE --solve hand --export OUT --json`: its summary."""
    r = subprocess.run([binary, "replay", take, "--solve", "hand", "--export", out, "--json"],
                       capture_output=True, text=True, timeout=WAIT_S * 4)
    check(r.returncode == 0, f"export to {out}: {r.stderr}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def check_exports(binary, out_dir, port, scene):
    """The take exported to glTF and BVH and imported by Blender's own importers: the
    skeleton's joints, the animation's frames and length; then the imported mesh, the
    user's own copy of the character, driven by the stream."""
    take = os.path.join(ROOT, "replay", "hand_finger_play.c3d")
    glb = export(binary, take, os.path.join(out_dir, "hand.glb"))
    bvh = export(binary, take, os.path.join(out_dir, "hand.bvh"))
    out = {}
    fps = scene.render.fps / scene.render.fps_base
    for name, summary, load in (
        ("glb", glb, lambda: bpy.ops.import_scene.gltf(filepath=glb["path"])),
        ("bvh", bvh, lambda: bpy.ops.import_anim.bvh(filepath=bvh["path"], use_fps_scale=True, update_scene_fps=False,
                                                      update_scene_duration=False)),
    ):
        before = set(bpy.data.objects)
        check(load() == {"FINISHED"}, f"Blender imports the {name}")
        new = [o for o in bpy.data.objects if o not in before]
        arm = next(o for o in new if o.type == "ARMATURE")
        action = arm.animation_data.action
        first, last = action.frame_range
        seconds = summary["frames"] / summary["rate_hz"]
        # Keys at the take's rate land on the scene's frames: the action spans the take's
        # length at the scene's rate, within a frame.
        span_s = (last - first) / fps
        check(abs(span_s - (summary["frames"] - 1) / summary["rate_hz"]) <= 1.0 / fps,
              f"{name}: action {first}..{last} at {fps} fps for {summary['frames']} frames at {summary['rate_hz']} Hz")
        check(len(arm.data.bones) == summary["points"], f"{name}: {len(arm.data.bones)} bones, {summary['points']} joints")
        out[name] = {"bones": len(arm.data.bones), "frame_range": [first, last], "take_seconds": seconds,
                     "meshes": [len(o.data.vertices) for o in new if o.type == "MESH"]}
    # The imported glTF mesh is a copy of the character: first Blender's own skinning of
    # it against the solved mesh of the same take (a point cache), then driven from the
    # stream.
    mesh = next(o for o in bpy.data.objects if o.type == "MESH" and o.parent and o.parent.type == "ARMATURE")
    out["glb_skin"] = skin_against_solve(binary, take, os.path.join(out_dir, "hand.pc2"), mesh, scene)
    scene.rigless_target = mesh
    rigless_live.connect("127.0.0.1", port)
    deadline, applied = time.time() + WAIT_S, 0
    while applied < 10:
        check(time.time() < deadline, f"the imported mesh was not driven: {rigless_live._state['message']}")
        applied += rigless_live.apply_newest(scene) == "applied"
        time.sleep(0.005)
    out["driven_import"] = {"object": mesh.name, "vertices": len(mesh.data.vertices), "frames_applied": applied}
    rigless_live.disconnect()
    scene.rigless_target = None
    return out


def skin_against_solve(binary, take, pc2_path, mesh, scene):
    """Blender's skinning of the imported glTF at take frames, against the point cache
    of the same take: mean and largest vertex distance, metres (in Blender's axes)."""
    summary = export(binary, take, pc2_path)
    data = open(pc2_path, "rb").read()
    points, samples = struct.unpack("<i", data[16:20])[0], struct.unpack("<i", data[28:32])[0]
    check(points == len(mesh.data.vertices), f"point cache of {points} points, mesh of {len(mesh.data.vertices)}")
    fps = scene.render.fps / scene.render.fps_base
    total, count, largest, frames = 0.0, 0, 0.0, []
    for f in [k * (samples - 1) // 4 for k in range(5)]:
        # The importer puts a key at time t on scene frame t * fps.
        at = f / summary["rate_hz"] * fps
        scene.frame_set(int(at), subframe=at - int(at))
        evaluated = mesh.evaluated_get(bpy.context.evaluated_depsgraph_get())
        skinned = evaluated.to_mesh()
        base = 32 + f * points * 12
        solved = struct.unpack(f"<{points * 3}f", data[base:base + points * 12])
        world = mesh.matrix_world
        for i, v in enumerate(skinned.vertices):
            x, y, z = solved[3 * i:3 * i + 3]
            d = ((world @ v.co) - mathutils.Vector((x, -z, y))).length
            total, count, largest = total + d, count + 1, max(largest, d)
        evaluated.to_mesh_clear()
        frames.append(f)
    scene.frame_set(scene.frame_start)
    return {"frames": frames, "mean_m": total / max(count, 1), "max_m": largest}


INSTALL_CHECK = """
import os, sys, bpy
zip_path, = sys.argv[1:]
ok = bpy.ops.preferences.addon_install(filepath=zip_path) == {"FINISHED"}
ok = ok and bpy.ops.preferences.addon_enable(module="rigless_live") == {"FINISHED"}
ok = ok and hasattr(bpy.types, "RIGLESS_PT_panel") and bpy.context.scene.rigless_port == 7878
print("installed" if ok else "not installed")
sys.stdout.flush()
os._exit(0)
"""


def check_zip_install(out_dir):
    """The add-on zipped as a user would zip it installs and enables through Blender's
    preferences (into a scripts folder of the test's own, not the user's)."""
    import zipfile
    src = os.path.join(ROOT, "clients", "blender", "rigless_live")
    zip_path = os.path.join(out_dir, "rigless_live.zip")
    with zipfile.ZipFile(zip_path, "w") as z:
        for name in sorted(os.listdir(src)):
            if name.endswith((".py", ".toml")):
                z.write(os.path.join(src, name), f"rigless_live/{name}")
    env = dict(os.environ, BLENDER_USER_SCRIPTS=os.path.join(out_dir, "scripts"),
               BLENDER_USER_CONFIG=os.path.join(out_dir, "config"))
    r = subprocess.run([sys.executable, "-c", INSTALL_CHECK, zip_path], capture_output=True, text=True,
                       env=env, timeout=WAIT_S * 2)
    check("installed" in r.stdout.splitlines(), f"the zip does not install: {r.stdout[-500:]} {r.stderr[-500:]}")
    check(os.path.isfile(os.path.join(out_dir, "scripts", "addons", "rigless_live", "__init__.py")),
          "the zip was installed elsewhere than the test's scripts folder")
    return True


def to_blender_axes(v):
    v = v.reshape(-1, 3)
    return np.stack([v[:, 0], -v[:, 2], v[:, 1]], axis=1).ravel()


def applied_diff(reference, actor=0):
    """The largest difference, metres, between the driven object's vertices and the
    stream's vertices of the frame the add-on applied last (read by the reference
    client, in Blender's axes); None when the reference did not get that frame."""
    f = rigless_live._state["applied"]
    want = None
    for _ in range(100):
        want = reference.get(f["frame"], actor=actor)
        if want is not None:
            break
        time.sleep(0.005)
    if want is None:
        return None
    obj = bpy.data.objects[rigless_live._state["object"]]
    co = np.empty(3 * len(obj.data.vertices), dtype=np.float32)
    obj.data.vertices.foreach_get("co", co)
    return float(np.abs(co - to_blender_axes(want)).max())


def check_actor_choice(binary, scene):
    """On the two-actor demo: following "Bob" applies Bob's frames (equal to the
    stream's actor 1 frames of the same number); "Carl" is refused, naming Ann and Bob."""
    port = free_port()
    demo = start_demo(binary, port, cast=("--actors", "2"))
    try:
        reference = Reference(port)
        reference.start()
        scene.rigless_target = None
        rigless_live.connect("127.0.0.1", port, actor="Bob")
        compared, max_diff, deadline = 0, 0.0, time.time() + WAIT_S
        while compared < 10:
            check(time.time() < deadline, f"only {compared} of Bob's frames compared: {rigless_live._state['message']}")
            if rigless_live.apply_newest(scene) != "applied":
                time.sleep(0.002)
                continue
            f = rigless_live._state["applied"]
            check(f["actor"] == 1, f"applied a frame of actor {f['actor']}, not Bob's (1)")
            diff = applied_diff(reference, actor=1)
            if diff is None:
                continue
            max_diff = max(max_diff, diff)
            compared += 1
        out = {"object": rigless_live._state["object"], "compared": compared, "max_diff_m": max_diff}
        rigless_live.connect("127.0.0.1", port, actor="Carl")
        deadline, status = time.time() + WAIT_S, None
        while status != "closed":
            check(time.time() < deadline, "an actor the stream lacks was not refused")
            status = rigless_live.apply_newest(scene)
            time.sleep(0.01)
        out["refused"] = rigless_live._state["message"]
        rigless_live.disconnect()
        return out
    finally:
        demo.terminate()
        demo.wait(timeout=20)


def main():
    binary, out_dir = sys.argv[1], sys.argv[2]
    os.makedirs(out_dir, exist_ok=True)
    result = {"zip_installs": check_zip_install(out_dir)}
    port = free_port()
    demo = start_demo(binary, port)
    try:
        reference = Reference(port)
        reference.start()
        rigless_live.register()
        scene = bpy.context.scene
        scene.rigless_host, scene.rigless_port = "127.0.0.1", port
        check(bpy.ops.rigless.connect() == {"FINISHED"}, "the connect operator runs")

        # 100 frames applied by the add-on, each compared with the stream's own.
        compared, max_diff, applied, seen = 0, 0.0, 0, set()
        deadline = time.time() + WAIT_S
        while compared < 100:
            check(time.time() < deadline, f"only {compared} frames compared in {WAIT_S} s: {rigless_live._state['message']}")
            if rigless_live.apply_newest(scene) != "applied":
                time.sleep(0.002)
                continue
            applied += 1
            f = rigless_live._state["applied"]
            diff = applied_diff(reference)
            if diff is None:
                continue
            max_diff = max(max_diff, diff)
            compared += 1
            seen.add(f["frame"])
        obj = bpy.data.objects[rigless_live._state["object"]]
        result.update(compared=compared, applied=applied, distinct_frames=len(seen), max_diff_m=max_diff,
                      vertices=len(obj.data.vertices), triangles=len(obj.data.polygons), object=obj.name)

        # Record about a second, then write the cache and play it on the timeline.
        scene.render.fps, scene.render.fps_base = 24, 1.0
        scene.frame_set(10)
        rigless_live.start_recording(scene)
        t0 = time.time()
        while time.time() - t0 < 1.0:
            rigless_live.apply_newest(scene)
            time.sleep(0.005)
        recorded_numbers = [n for n, _ in rigless_live._state["receiver"].recording]
        path, samples, take = rigless_live.stop_recording(scene, directory=out_dir)
        with open(path, "rb") as fh:
            head = fh.read(32)
            size = fh.seek(0, 2)
        sig, (version, points, start, rate, count) = head[:12], struct.unpack("<iiffi", head[12:32])
        check(sig == b"POINTCACHE2\0" and version == 1 and start == 0.0 and rate == 1.0, f"PC2 header {head!r}")
        expected = recorded_numbers[-1] - recorded_numbers[0] + 1
        check(count == samples == expected, f"{count} samples written, {samples} said, frames {recorded_numbers[0]}..{recorded_numbers[-1]}")
        check(points == result["vertices"] and size == 32 + 12 * points * count, f"{points} points, {size} bytes")
        # Scene frame 10 + k shows sample k × 120 / 24 = 5k.
        mod = take.modifiers["rigless take"]
        played = 0.0
        for k in (0, 2):
            scene.frame_set(10 + k)
            deps = bpy.context.evaluated_depsgraph_get()
            mesh = take.evaluated_get(deps).to_mesh()
            co = np.empty(3 * len(mesh.vertices), dtype=np.float32)
            mesh.vertices.foreach_get("co", co)
            take.evaluated_get(deps).to_mesh_clear()
            with open(path, "rb") as fh:
                fh.seek(32 + 12 * points * 5 * k)
                want = np.frombuffer(fh.read(12 * points), dtype="<f4")
            played = max(played, float(np.abs(co - want).max()))
        check(played == 0.0, f"the take plays other samples than recorded (off by {played} m)")
        result.update(pc2_samples=count, pc2_frames_recorded=len(recorded_numbers),
                      frame_scale=mod.frame_scale, playback_max_diff_m=played)
        rigless_live.disconnect()
        result.update(check_exports(binary, out_dir, port, scene))

        # A mesh of another vertex count is refused, and left as it was.
        bpy.ops.mesh.primitive_cube_add()
        cube = bpy.context.active_object
        before = [tuple(v.co) for v in cube.data.vertices]
        scene.rigless_target = cube
        rigless_live.connect("127.0.0.1", port)
        deadline, status = time.time() + WAIT_S, None
        while status != "refused":
            check(time.time() < deadline, "a wrong vertex count was not refused")
            status = rigless_live.apply_newest(scene)
            time.sleep(0.01)
        result["refused"] = rigless_live._state["message"]
        check([tuple(v.co) for v in cube.data.vertices] == before, "the refused mesh was changed")
        rigless_live.disconnect()
        result["actor_choice"] = check_actor_choice(binary, scene)
        rigless_live.unregister()
    finally:
        demo.terminate()
        demo.wait(timeout=20)
    print(json.dumps(result))


if __name__ == "__main__":
    try:
        main()
    except Exception as e:  # noqa: BLE001 (report and fail)
        print(f"add-on check failed: {type(e).__name__}: {e}", file=sys.stderr)
        sys.stdout.flush()
        os._exit(1)
    # bpy 4.2 as a Python module crashes in its teardown at interpreter exit once its glTF
    # importer has run (any .glb: `import bpy; bpy.ops.import_scene.gltf(filepath=...)`
    # alone exits with SIGSEGV), so leave without it once the results are out.
    sys.stdout.flush()
    os._exit(0)
