"""rigless live: drives a Blender mesh from a running rigless daemon's vertex stream.

A panel in the 3D view's sidebar (tab "rigless"): host and port of the stream (TCP,
127.0.0.1:7878 by default), the actor to follow on a stage of several (by name; empty:
the first), an optional mesh of your own to drive, Connect, Disconnect and Record. The stream is read on a thread; a timer on Blender's main thread applies the
newest frame with `foreach_set` (older frames are dropped, so Blender never falls
behind). Without a mesh of your own, one is made from the stream's topology. Record
keeps every frame and, on stop, writes a PC2 point cache at the stream's rate and adds a
copy of the object that plays it (a Mesh Cache modifier) on the timeline.

Coordinates: the stream is right-handed, Y up, metres; Blender is Z up, so a point
(x, y, z) becomes (x, -z, y), as Blender's glTF importer converts.
"""

bl_info = {
    "name": "rigless live",
    "author": "rigless",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > rigless",
    "description": "Drive a mesh from a rigless vertex stream; record takes as point caches",
    "category": "Animation",
}

import os
import tempfile
import time

import bpy
import numpy as np

from . import stream

# How often the main thread applies the newest frame, seconds.
APPLY_INTERVAL_S = 1.0 / 60.0

# The add-on's state outside Blender's data: the receiver thread and what was applied.
_state = {
    "receiver": None,
    "serial": 0,
    "object": None,
    "applied": None,
    "applied_count": 0,
    "refused": None,
    "message": "not connected",
    "record_start_frame": None,
}


def to_blender(vertices_m):
    """Stream positions (x, y, z per vertex, Y up) as Blender coordinates (Z up), flat."""
    v = np.frombuffer(vertices_m, dtype=np.float32).reshape(-1, 3)
    out = np.empty_like(v)
    out[:, 0], out[:, 1], out[:, 2] = v[:, 0], -v[:, 2], v[:, 1]
    return out.ravel()


def _who(t):
    """The actor a topology is for, with its character when its name is another."""
    return t["actor"] if t["actor"] == t["character"] else f"{t['actor']} ({t['character']})"


def _mesh_for(scene, t):
    """The object the stream drives: the user's target (checked) or one made from the
    topology. Returns (object, None) or (None, why it is refused)."""
    target = scene.rigless_target
    n = t["vertex_count"]
    if target is not None:
        have = len(target.data.vertices)
        if have != n:
            return None, (
                f"refused: the stream's {_who(t)!r} has {n} vertices, "
                f"{target.name!r} has {have}; import the asset without merging vertices "
                "(glTF importer: untick Merge Vertices) or clear the target"
            )
        return target, None
    name = f"rigless {t['actor']}"
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "MESH" or len(obj.data.vertices) != n:
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata([(0.0, 0.0, 0.0)] * n, [], [tuple(tri) for tri in t["triangles"]])
        mesh.update()
        obj = bpy.data.objects.new(name, mesh)
        scene.collection.objects.link(obj)
    return obj, None


def apply_newest(scene):
    """Applies the newest frame, if it is new, to the driven mesh. Returns what it did
    ("applied", "waiting", "refused", "closed"); the timer calls it, tests may too."""
    r = _state["receiver"]
    if r is None:
        return "closed"
    serial, t, f = r.newest()
    if serial != _state["serial"] and t is not None:
        _state["serial"] = serial
        obj, why = _mesh_for(scene, t)
        _state["object"], _state["refused"] = (obj.name if obj else None), why
        _state["applied"] = None
    if _state["refused"]:
        _state["message"] = _state["refused"]
        return "refused"
    if r.closed.is_set() and (f is None or f is _state["applied"]):
        _state["message"] = r.error or (f"server said goodbye: {r.goodbye}" if r.goodbye else "connection closed")
        return "closed"
    if f is None or f is _state["applied"] or _state["object"] is None:
        _state["message"] = "connected, waiting for frames" if t else "connected, waiting for the topology"
        return "waiting"
    obj = bpy.data.objects.get(_state["object"])
    if obj is None:
        _state["serial"] = 0
        return "waiting"
    obj.data.vertices.foreach_set("co", to_blender(f["vertices_m"]))
    obj.data.update()
    _state["applied"], _state["applied_count"] = f, _state["applied_count"] + 1
    _state["message"] = (f"{t['actor']}: frame {f['frame']}, {r.frames_received} received, "
                         f"{_state['applied_count']} applied, solve {f['solve_ms']:.2f} ms")
    return "applied"


def _timer():
    if _state["receiver"] is None:
        return None
    apply_newest(bpy.context.scene)
    return APPLY_INTERVAL_S


def connect(host, port, actor=""):
    """Starts following the stream at host:port: the actor named `actor` (the first when
    empty)."""
    disconnect()
    r = stream.Receiver(host, port, actor=actor)
    _state.update(receiver=r, serial=0, object=None, applied=None, applied_count=0, refused=None,
                  message=f"connecting to {host}:{port}")
    r.start()
    if not bpy.app.timers.is_registered(_timer):
        bpy.app.timers.register(_timer, first_interval=APPLY_INTERVAL_S, persistent=True)


def disconnect():
    r = _state["receiver"]
    if r is not None:
        r.close()
        r.join(timeout=2.0)
    _state["receiver"] = None
    _state["message"] = "not connected"
    if bpy.app.timers.is_registered(_timer):
        bpy.app.timers.unregister(_timer)


def start_recording(scene):
    r = _state["receiver"]
    if r is None:
        raise RuntimeError("connect first")
    _state["record_start_frame"] = scene.frame_current
    r.start_recording()


def stop_recording(scene, directory=None):
    """Writes what was recorded as a PC2 cache (one sample per stream frame, Blender
    axes) and adds a copy of the driven object playing it from the frame where recording
    started. Returns (path, samples, the new object)."""
    r = _state["receiver"]
    if r is None:
        raise RuntimeError("not connected")
    frames = r.stop_recording()
    _, t, _ = r.newest()
    obj = bpy.data.objects.get(_state["object"] or "")
    if not frames or t is None or obj is None:
        raise RuntimeError("nothing was recorded")
    samples = [to_blender(v) for v in stream.fill_gaps(frames)]
    if directory is None:
        directory = bpy.path.abspath("//") if bpy.data.filepath else tempfile.gettempdir()
    path = os.path.join(directory, f"rigless_{t['character']}_{time.strftime('%Y%m%d-%H%M%S')}.pc2")
    stream.write_pc2(path, samples, t["vertex_count"])
    take = obj.copy()
    take.data = obj.data.copy()
    take.name = f"{obj.name} take"
    scene.collection.objects.link(take)
    mod = take.modifiers.new("rigless take", "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = path
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    # Cache samples per scene frame: the stream's rate over the scene's. The modifier
    # reads sample `scene frame × frame_scale − frame_start`, so the frame where recording
    # started shows the first sample.
    fps = scene.render.fps / scene.render.fps_base
    mod.frame_scale = t["rate_hz"] / fps
    start = _state["record_start_frame"]
    mod.frame_start = (scene.frame_current if start is None else start) * mod.frame_scale
    return path, len(samples), take


class RIGLESS_OT_connect(bpy.types.Operator):
    """Connect to a rigless vertex stream and drive the mesh from it"""
    bl_idname = "rigless.connect"
    bl_label = "Connect"

    def execute(self, context):
        s = context.scene
        connect(s.rigless_host, s.rigless_port, s.rigless_actor.strip())
        return {"FINISHED"}


class RIGLESS_OT_disconnect(bpy.types.Operator):
    """Stop reading the stream (the mesh keeps its last frame)"""
    bl_idname = "rigless.disconnect"
    bl_label = "Disconnect"

    def execute(self, context):
        disconnect()
        return {"FINISHED"}


class RIGLESS_OT_record(bpy.types.Operator):
    """Start recording every frame; again to stop, write a point cache and add it on the timeline"""
    bl_idname = "rigless.record"
    bl_label = "Record"

    def execute(self, context):
        r = _state["receiver"]
        if r is None:
            self.report({"ERROR"}, "connect first")
            return {"CANCELLED"}
        if r.recording is None:
            start_recording(context.scene)
            self.report({"INFO"}, "recording")
        else:
            try:
                path, n, take = stop_recording(context.scene)
            except RuntimeError as e:
                self.report({"ERROR"}, str(e))
                return {"CANCELLED"}
            self.report({"INFO"}, f"{n} frames written to {path}; {take.name!r} plays them")
        return {"FINISHED"}


class RIGLESS_PT_panel(bpy.types.Panel):
    bl_label = "rigless live"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "rigless"

    def draw(self, context):
        s, col = context.scene, self.layout.column()
        row = col.row()
        row.prop(s, "rigless_host")
        row.prop(s, "rigless_port")
        col.prop(s, "rigless_actor")
        col.prop(s, "rigless_target")
        row = col.row()
        r = _state["receiver"]
        if r is None:
            row.operator("rigless.connect")
        else:
            row.operator("rigless.disconnect")
            recording = r.recording is not None
            row.operator("rigless.record", text="Stop and save" if recording else "Record",
                         depress=recording)
        col.label(text=_state["message"])


_classes = (RIGLESS_OT_connect, RIGLESS_OT_disconnect, RIGLESS_OT_record, RIGLESS_PT_panel)


def register():
    bpy.types.Scene.rigless_host = bpy.props.StringProperty(
        name="Host", default="127.0.0.1", description="The rigless daemon's address")
    bpy.types.Scene.rigless_port = bpy.props.IntProperty(
        name="Port", default=7878, min=1, max=65535, description="The vertex stream's TCP port")
    bpy.types.Scene.rigless_actor = bpy.props.StringProperty(
        name="Actor", default="",
        description="On a stage of several actors, the one to follow, by name (empty: the first)")
    bpy.types.Scene.rigless_target = bpy.props.PointerProperty(
        name="Mesh", type=bpy.types.Object, poll=lambda _self, o: o.type == "MESH",
        description="Your own copy of the character's mesh (same vertex order and count); "
                    "empty: make one from the stream")
    for c in _classes:
        bpy.utils.register_class(c)


def unregister():
    disconnect()
    for c in reversed(_classes):
        bpy.utils.unregister_class(c)
    del bpy.types.Scene.rigless_host
    del bpy.types.Scene.rigless_port
    del bpy.types.Scene.rigless_target
    del bpy.types.Scene.rigless_actor
