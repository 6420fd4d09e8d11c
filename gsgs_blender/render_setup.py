"""Scene settings under which Blender renders imported splats as the engine does.

`splat_render_settings(scene)` lists (owner, attribute, value, why) for:
  * Cycles: transparent bounces high enough that a ray crosses every splat on its way (each proxy
    is two surfaces), with the minimum equal to the maximum so Russian roulette never ends a
    path early (noise); one sample through the pixel centre (a 0.01 px filter), as the engine
    evaluates each pixel once at its centre; no denoising (it would blur the splats);
  * colour management, two modes:
      - "EXACT": the Raw view transform with the splats' colours kept as the engine's display (sRGB)
        values, so Blender blends them exactly as the engine does (alpha-compositing in display space);
      - "LINEAR": the Standard view transform with the colours converted to scene-linear: right next
        to other lit objects, but semi-transparent edges blend in linear light, which the engine does
        not (docs/blender_fidelity.md measures both);
    either way no look, exposure 0, gamma 1 (AgX / Filmic would change every colour);
  * EEVEE: blended transparency needs no extra setting; one sample per pixel like Cycles.
`apply(scene)` changes only what differs and returns one line per change (the Info line reports them).
"""

from __future__ import annotations

# Cycles' maximum: a path ends when it escapes, so rays that cross few splats pay nothing for it.
TRANSPARENT_BOUNCES = 1024


COLOUR_ITEMS = [
    ("EXACT", "Exact (Raw)", "Raw view transform, splat colours kept as the engine's display values: blends "
                             "exactly as the engine (best fidelity; other lit objects look flat)"),
    ("LINEAR", "Linear (Standard)", "Standard view transform, splat colours converted to scene-linear: fits "
                                    "next to other objects; soft splat edges blend in linear light"),
]
COLOUR_MODES = tuple(item[0] for item in COLOUR_ITEMS)
DEFAULT_COLOUR_MODE = "EXACT"


def splat_render_settings(scene, colour_mode: str = DEFAULT_COLOUR_MODE) -> list[tuple[object, str, object, str]]:
    if colour_mode not in COLOUR_MODES:
        raise ValueError(f"colour mode {colour_mode!r}: choose one of {', '.join(COLOUR_MODES)}")
    cyc = scene.cycles
    vs = scene.view_settings
    out = [
        (cyc, "transparent_max_bounces", TRANSPARENT_BOUNCES, "a ray crosses every splat"),
        (cyc, "min_transparent_bounces", TRANSPARENT_BOUNCES, "no Russian roulette on splat paths"),
        (cyc, "samples", 1, "one sample per pixel, as the engine"),
        (cyc, "use_adaptive_sampling", False, "one sample everywhere"),
        (cyc, "use_denoising", False, "denoising blurs splats"),
        (cyc, "filter_width", 0.01, "each pixel sampled at its centre, as the engine"),
        (cyc, "sample_clamp_indirect", 0.0, "no clamping of splat colours"),
        (vs, "view_transform", "Raw" if colour_mode == "EXACT" else "Standard",
         "splats blend in display space, as the engine" if colour_mode == "EXACT"
         else "linearised splat colours come back as the engine's sRGB values"),
        (vs, "look", "None", "no look on top of the display transform"),
        (vs, "exposure", 0.0, "no exposure change"),
        (vs, "gamma", 1.0, "no gamma change"),
        (scene.display_settings, "display_device", "sRGB", "the engine's images are sRGB"),
    ]
    eevee = getattr(scene, "eevee", None)
    if eevee is not None and hasattr(eevee, "taa_render_samples"):
        out.append((eevee, "taa_render_samples", 1, "one EEVEE sample, as the engine"))
    return out


def pending_changes(scene, colour_mode: str = DEFAULT_COLOUR_MODE) -> list[tuple[object, str, object, str]]:
    """The settings that differ from what splats need."""
    pending = []
    for owner, attr, value, why in splat_render_settings(scene, colour_mode):
        if not hasattr(owner, attr):
            continue  # another Blender version: the setting does not exist there
        current = getattr(owner, attr)
        same = abs(current - value) < 1e-9 if isinstance(value, float) else current == value
        if not same:
            pending.append((owner, attr, value, why))
    return pending


def apply(scene, colour_mode: str = DEFAULT_COLOUR_MODE, objects=()) -> list[str]:
    """Set the splat render settings on `scene` and the colour mode on the splat `objects`;
    one 'what: old -> new (why)' line per change."""
    from . import node_groups

    lines = []
    for owner, attr, value, why in pending_changes(scene, colour_mode):
        old = getattr(owner, attr)
        setattr(owner, attr, value)
        lines.append(f"{attr}: {old} -> {value} ({why})")
    linear = colour_mode == "LINEAR"
    for obj in objects:
        mod = obj.modifiers.get(node_groups.MODIFIER_NAME)
        if mod is None or mod.node_group is None:
            continue
        old = bool(node_groups.get_modifier_input(mod, "Linear Colours"))
        if old != linear:
            node_groups.set_modifier_input(mod, "Linear Colours", linear)
            obj.update_tag()
            lines.append(f"{obj.name} Linear Colours: {old} -> {linear} "
                         f"(matches the {colour_mode.lower()} colour mode)")
    return lines
