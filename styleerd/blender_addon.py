"""The styleerd Blender add-on: a panel on the armature (Properties > Armature > styleerd) with
the target style, intensity, mixture and the input's labels, and "Stylise action", which writes
the active action in the target style as a new action (the original is kept).

Install: styleerd in Blender's Python (``pip install styleerd`` with Blender's interpreter, or
``styleerd[blender]`` beside the ``bpy`` module), then Edit > Preferences > Add-ons > Install
from Disk: this file (``python -c "import styleerd.blender_addon as a; print(a.__file__)"``
prints where it is). Headless: ``import styleerd.blender_addon as a; a.register()``, then
``bpy.ops.styleerd.stylise_action()`` on the active armature.
"""

from functools import cache

import bpy

from styleerd.errors import StyleERDError
from styleerd.model.stored import load_generator_weights
from styleerd.models import LICENCE
from styleerd.runtime.fbx import read_armature, write_action
from styleerd.runtime.offline import TransferOptions, transfer_motion
from styleerd.runtime.stylizer import parse_mix, target_weights

bl_info = {
    "name": "styleerd: motion style transfer",
    "author": "styleerd",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "Properties > Armature > styleerd",
    "description": "Stylise an armature's action (elderly, exhausted, feminine, ...) with the Style-ERD network",
    "category": "Animation",
}

INFER = "(infer)"


@cache
def _model(name: str = ""):
    return load_generator_weights(name or None)


def _items(names: tuple[str, ...], infer: bool = False) -> list[tuple[str, str, str]]:
    return ([(INFER, "infer from the motion", "inferred online from the frames")] if infer else []) + [
        (n, n, n) for n in names
    ]


# enum items must stay referenced while Blender shows them
_STYLES = _items(_model().config.styles)
_INPUT_STYLES = _items(_model().config.input_styles, infer=True)
_CONTENTS = _items(_model().config.contents, infer=True)


class StyleERDSettings(bpy.types.PropertyGroup):
    style: bpy.props.EnumProperty(name="Style", items=_STYLES, description="the target style")
    intensity: bpy.props.FloatProperty(
        name="Intensity", default=1.0, min=0.0, max=2.0, description="0 = neutral, 1 = the style, up to 2 exaggerates"
    )
    mix: bpy.props.StringProperty(
        name="Mix", default="", description="a mixture instead of the style, e.g. elderly=0.5,feminine=0.5"
    )
    input_style: bpy.props.EnumProperty(name="Input style", items=_INPUT_STYLES, description="the action's own style")
    content: bpy.props.EnumProperty(
        name="Content", items=_CONTENTS, description="what the action does (walk, run, ...)"
    )
    cleanup: bpy.props.BoolProperty(name="Pin planted feet", default=True)


class STYLEERD_OT_stylise_action(bpy.types.Operator):
    """Write the active action in the target style as a new action"""

    bl_idname = "styleerd.stylise_action"
    bl_label = "Stylise action"
    bl_options = {"REGISTER", "UNDO"}  # noqa: RUF012  Blender reads it as a class attribute

    @classmethod
    def poll(cls, context) -> bool:
        arm = context.active_object
        return (
            arm is not None
            and arm.type == "ARMATURE"
            and arm.animation_data is not None
            and arm.animation_data.action is not None
        )

    def execute(self, context):
        arm, s, scene = context.active_object, context.active_object.styleerd, context.scene
        source = arm.animation_data.action
        model = _model()
        try:
            mix = parse_mix(s.mix)  # typed in, it replaces the style chosen
            target = target_weights(model, None if mix else s.style, s.intensity, mix)
            first, last = (int(round(x)) for x in source.frame_range)
            frames = range(first, last + 1)
            motion = read_armature(arm, frames, scene.render.fps / scene.render.fps_base)
            options = TransferOptions(
                target,
                None if s.input_style == INFER else s.input_style,
                None if s.content == INFER else s.content,
                cleanup=s.cleanup,
            )
            out = transfer_motion(motion, model, model.meta["data"]["fps"], options, where=arm.name)
        except StyleERDError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        source.use_fake_user = True  # the original stays in the file when the new action takes its place
        tag = "+".join(f"{k}{v:g}" if v != 1 else k for k, v in target.items())
        action = write_action(arm, out, frames, f"{source.name}-{tag}")
        scene.frame_set(first)
        self.report({"INFO"}, f"wrote action {action.name!r}: {len(frames)} frames, target {target}")
        return {"FINISHED"}


class STYLEERD_PT_panel(bpy.types.Panel):
    bl_label = "styleerd"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "data"

    @classmethod
    def poll(cls, context) -> bool:
        return context.active_object is not None and context.active_object.type == "ARMATURE"

    def draw(self, context):
        s, layout = context.active_object.styleerd, self.layout
        for name in ("style", "intensity", "mix", "input_style", "content", "cleanup"):
            layout.prop(s, name)
        layout.operator(STYLEERD_OT_stylise_action.bl_idname)
        layout.label(text=f"model licence: {LICENCE}")


CLASSES = (StyleERDSettings, STYLEERD_OT_stylise_action, STYLEERD_PT_panel)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Object.styleerd = bpy.props.PointerProperty(type=StyleERDSettings)


def unregister() -> None:
    del bpy.types.Object.styleerd
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
