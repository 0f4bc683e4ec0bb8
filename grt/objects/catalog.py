"""The built-in household objects: one builder per object, real-world sizes in meters.

Each builder returns ``(solid, regions)`` in its own construction frame: ``solid`` is a
``manifold3d.Manifold`` or ``trimesh.Trimesh``; ``regions`` maps a part name to an axis-aligned box
``(2, 3)`` (min corner, max corner) in meters. :mod:`grt.objects` then moves both so the object
rests on ``z = 0``, centered in x/y. Sizes follow common household items (YCB where one exists).
Every object has a part narrower than ~0.07 m so a Franka Panda gripper (0.08 m opening) can grasp it.
"""

from __future__ import annotations

import manifold3d as m3
import numpy as np

from grt.objects.shapes import arc, grid_box, revolve, rotate_z_to, sweep_profile, sweep_tube

PI = np.pi


def _box(lo, hi) -> np.ndarray:
    return np.array([lo, hi], dtype=np.float64)


def _cat(*parts) -> np.ndarray:
    return np.concatenate([np.atleast_2d(np.asarray(p, np.float64)) for p in parts])


def _capsule_profile(length: float, radius: float, end_radius: float | None = None) -> np.ndarray:
    """``(r, z)`` profile of a rod from ``z = 0`` to ``length`` with rounded ends."""
    f = radius if end_radius is None else end_radius
    return _cat((0, 0), arc((radius - f, f), f, -PI / 2, 0), arc((radius - f, length - f), f, 0, PI / 2),
                (0, length))


def mug():
    r, h, t, tb = 0.041, 0.096, 0.005, 0.008  # outer radius, height, wall, bottom thickness
    prof = _cat((0, 0), arc((r - 0.004, 0.004), 0.004, -PI / 2, 0), arc((r - t / 2, h - t / 2), t / 2, 0, PI),
                arc((r - t - 0.006, tb + 0.006), 0.006, 0, -PI / 2), (0, tb))
    body = revolve(prof, segments=48, min_spacing=0.003)
    rc, rh, zc = 0.027, 0.0065, 0.052  # handle: centerline radius, tube radius, height
    ring = arc((rc, 0), rh, -PI / 2, 3 * PI / 2, n=17)[:-1]
    handle = m3.Manifold.revolve(m3.CrossSection([ring]), 36).rotate((90.0, 0.0, 0.0)).translate((r + 0.003, 0, zc))
    cavity = revolve(_cat((0, tb), arc((r - t - 0.006, tb + 0.006), 0.006, -PI / 2, 0), (r - t, h + 0.01),
                          (0, h + 0.01)), segments=48)
    solid = (body + handle) - cavity
    x_out = r + 0.003 + rc + rh
    regions = {"handle": _box((r - 0.002, -rh - 0.002, zc - rc - rh - 0.002), (x_out + 0.002, rh + 0.002, zc + rc + rh + 0.002)),
               "rim": _box((-r - 0.002, -r - 0.002, h - 0.012), (r + 0.002, r + 0.002, h + 0.002)),
               "body": _box((-r - 0.002, -r - 0.002, 0), (r + 0.002, r + 0.002, h))}
    return solid, regions


def bottle():
    r, h, rn = 0.033, 0.225, 0.0135  # body radius, height, neck radius
    s = np.linspace(0, 1, 40)
    shoulder = np.stack([rn + (r - rn) * 0.5 * (1 + np.cos(PI * s)), 0.15 + 0.04 * s], 1)
    prof = _cat((0, 0), arc((r - 0.006, 0.006), 0.006, -PI / 2, 0), shoulder, (rn, 0.2), (0.0155, 0.2),
                arc((0.0155 - 0.002, h - 0.002), 0.002, 0, PI / 2), (0, h))
    regions = {"cap": _box((-0.017, -0.017, 0.2), (0.017, 0.017, h)),
               "neck": _box((-0.02, -0.02, 0.17), (0.02, 0.02, 0.2)),
               "body": _box((-r - 0.002, -r - 0.002, 0), (r + 0.002, r + 0.002, 0.15))}
    return revolve(prof, segments=40, min_spacing=0.003), regions


def bowl():
    rf, rt, h, t = 0.035, 0.08, 0.055, 0.005  # foot radius, top radius, height, wall
    a = np.linspace(0, PI / 2, 40)
    outer = np.stack([rf + (rt - rf) * np.sin(a), h - h * np.cos(a)], 1)
    inner = np.stack([rf + (rt - rf - t) * np.sin(a), h - (h - t) * np.cos(a)], 1)[::-1]
    prof = _cat((0, 0), outer, arc((rt - t / 2, h), t / 2, 0, PI), inner, (0, t))
    regions = {"rim": _box((-rt - 0.002, -rt - 0.002, h - 0.012), (rt + 0.002, rt + 0.002, h + t / 2 + 0.002)),
               "base": _box((-rf - 0.005, -rf - 0.005, 0), (rf + 0.005, rf + 0.005, 0.012))}
    return revolve(prof, segments=56, min_spacing=0.003), regions


def can():
    r, h, f = 0.033, 0.122, 0.004
    prof = _cat((0, 0), arc((r - f, f), f, -PI / 2, 0), arc((r - f, h - f), f, 0, PI / 2), (0, h))
    regions = {"top": _box((-r - 0.002, -r - 0.002, h - 0.01), (r + 0.002, r + 0.002, h)),
               "body": _box((-r - 0.002, -r - 0.002, 0.01), (r + 0.002, r + 0.002, h - 0.01)),
               "bottom": _box((-r - 0.002, -r - 0.002, 0), (r + 0.002, r + 0.002, 0.01))}
    return revolve(prof, segments=40, min_spacing=0.003), regions


def cup():
    rb, rt, h, t, tb = 0.027, 0.04, 0.1, 0.003, 0.005  # bottom/top radius, height, wall, bottom
    prof = _cat((0, 0), arc((rb - 0.003, 0.003), 0.003, -PI / 2, -0.13), (rt, h - t / 2),
                arc((rt - t / 2, h - t / 2), t / 2 + 1e-9, 0, PI)[1:], (rb - t + 0.0003, tb), (0, tb))
    regions = {"rim": _box((-rt - 0.002, -rt - 0.002, h - 0.012), (rt + 0.002, rt + 0.002, h + 0.002)),
               "body": _box((-rt - 0.002, -rt - 0.002, 0), (rt + 0.002, rt + 0.002, h))}
    return revolve(prof, segments=48, min_spacing=0.0025), regions


def screwdriver():
    rh, lh, rs, ls = 0.015, 0.1, 0.003, 0.1  # handle radius/length, shaft radius/length
    prof = _cat((0, 0), arc((rh - 0.006, 0.006), 0.006, -PI / 2, 0), arc((rh - 0.005, lh - 0.005), 0.005, 0, PI / 2),
                (0.008, lh), (0.0045, lh + 0.008), (rs, lh + 0.012), (rs, lh + ls - 0.008), (0.0015, lh + ls - 0.001),
                arc((0.0, lh + ls - 0.0015), 0.0015, 0, PI / 2))
    solid = rotate_z_to(revolve(prof, segments=24, min_spacing=0.002), "x")
    regions = {"handle": _box((0, -rh, -rh), (lh, rh, rh)),
               "shaft": _box((lh, -0.005, -0.005), (lh + ls - 0.008, 0.005, 0.005)),
               "tip": _box((lh + ls - 0.01, -0.004, -0.004), (lh + ls, 0.004, 0.004))}
    return solid, regions


def hammer():
    rh, lh, rk, lk = 0.0125, 0.3, 0.016, 0.11  # handle radius/length, head radius/length
    handle = rotate_z_to(revolve(_capsule_profile(lh, rh, 0.006), segments=24, min_spacing=0.004), "x")
    head = rotate_z_to(revolve(_capsule_profile(lk, rk, 0.004), segments=32, min_spacing=0.003), "y")
    head = head.translate((lh - rk, -lk / 2, rk - rh))
    regions = {"head": _box((lh - 2 * rk - 0.002, -lk / 2 - 0.002, -rh - 0.002), (lh + 0.002, lk / 2 + 0.002, 2 * rk - rh + 0.002)),
               "handle": _box((0, -rh - 0.002, -rh - 0.002), (lh - 2 * rk - 0.002, rh + 0.002, rh + 0.002))}
    return handle + head, regions


def sugar_box():
    size = (0.09, 0.045, 0.17)  # as YCB 004_sugar_box
    lo = tuple(-s / 2 for s in size[:2]) + (0.0,)
    hi = tuple(s / 2 for s in size[:2]) + (size[2],)
    regions = {"top": _box((lo[0], lo[1], hi[2] - 0.02), hi), "body": _box(lo, hi)}
    return grid_box(lo, hi, 0.0075), regions


def spray_bottle():
    r, h, rn = 0.035, 0.16, 0.014  # body radius/height, neck radius
    body = revolve(_cat((0, 0), arc((r - 0.006, 0.006), 0.006, -PI / 2, 0), arc((r - 0.01, h - 0.01), 0.01, 0, PI / 2),
                        (rn, h), (rn, h + 0.03), (0, h + 0.03)), segments=40, min_spacing=0.003)
    head_len, head_r = 0.07, 0.016
    head_prof = _cat((0, 0), arc((head_r - 0.006, 0.006), 0.006, -PI / 2, 0), (head_r, head_len - 0.012),
                     (0.006, head_len - 0.006), (0.0045, head_len), (0, head_len))
    head = rotate_z_to(revolve(head_prof, segments=28, min_spacing=0.003), "x").translate((-0.025, 0, h + 0.038))
    trigger = revolve(_capsule_profile(0.045, 0.006), segments=24, min_spacing=0.003).translate((0.03, 0, h - 0.012))
    regions = {"nozzle": _box((0.032, -0.008, h + 0.03), (0.047, 0.008, h + 0.046)),
               "trigger": _box((0.022, -0.008, h - 0.014), (0.038, 0.008, h + 0.026)),
               "head": _box((-0.027, -head_r - 0.002, h + 0.02), (0.047, head_r + 0.002, h + 0.056)),
               "body": _box((-r - 0.002, -r - 0.002, 0), (r + 0.002, r + 0.002, h))}
    return body + head + trigger, regions


def banana():
    bend, length, rmax = 0.13, 0.19, 0.018  # centerline bend radius, arc length, max radius
    half = length / (2 * bend)

    def centerline(t):
        a = half * np.sin(t)
        return np.stack([bend * np.sin(a), bend * (1 - np.cos(a)), np.zeros_like(a)], 1)

    def radius(t):
        return rmax * np.cos(t) ** 0.8

    mesh = sweep_tube(centerline, radius, rings=46, segments=24)
    end = bend * np.sin(half)
    regions = {"stem_end": _box((-end - 0.005, -0.02, -0.02), (-end + 0.035, bend * (1 - np.cos(half)) + 0.02, 0.02)),
               "tip_end": _box((end - 0.035, -0.02, -0.02), (end + 0.005, bend * (1 - np.cos(half)) + 0.02, 0.02)),
               "middle": _box((-0.03, -0.02, -0.02), (0.03, 0.02, 0.02))}
    return mesh, regions


def plug():
    # USB-A-like plug lying along x: grip body, then a metal head; grid lines coincide at the joint
    # so the Boolean union adds no sliver triangles.
    body = grid_box((0.0, -0.008, 0.0), (0.035, 0.008, 0.008), 0.002)
    head = grid_box((0.031, -0.006, 0.002), (0.047, 0.006, 0.006), 0.002)
    regions = {"head": _box((0.035, -0.0065, 0.0015), (0.0475, 0.0065, 0.0065)),
               "body": _box((0.0, -0.0085, 0.0), (0.035, 0.0085, 0.0085))}
    return body + head, regions


def usb_plug():
    # A USB-A-like plug standing on its connector for insertion: a flat metal head (12 x 4.5 x 12 mm)
    # under a grip body (18 x 10.5 x 30 mm) that the fingers pinch across y. Grid lines coincide at the
    # joint (1.5 mm spacing) so the Boolean union adds no sliver triangles.
    head = grid_box((-0.006, -0.00225, 0.0), (0.006, 0.00225, 0.012), 0.0015)
    grip = grid_box((-0.009, -0.00525, 0.012), (0.009, 0.00525, 0.042), 0.0015)
    # (regions get 1 mm of padding: they stay disjoint, the shoulder plane z = 12 mm in neither)
    regions = {"head": _box((-0.0065, -0.0028, -0.0005), (0.0065, 0.0028, 0.0105)),
               "grip": _box((-0.0095, -0.0058, 0.0135), (0.0095, 0.0058, 0.0425))}
    return head + grip, regions


def round_peg():
    # A round peg standing on its pin for insertion: a 10 mm pin, 12 mm long, under a 16 mm grip
    # cylinder 30 mm tall with rounded top edges and two milled flats (13 mm apart) where the fingers
    # hold it: on a bare cylinder flat finger pads touch a line and the peg swings about it.
    rp, lp, rg, hg, flat = 0.005, 0.012, 0.008, 0.042, 0.0065
    prof = _cat((0, 0), (rp, 0), (rp, lp), (rg, lp), arc((rg - 0.002, hg - 0.002), 0.002, 0, PI / 2, n=8), (0, hg))
    solid = revolve(prof, segments=40, min_spacing=0.0012)
    flats = grid_box((-0.01, -flat, lp + 0.004), (0.01, flat, hg + 0.001), 0.0015)
    keep = grid_box((-0.01, -0.01, -0.001), (0.01, 0.01, lp + 0.004), 0.0015)
    solid = solid ^ (flats + keep)
    regions = {"head": _box((-rp - 0.0005, -rp - 0.0005, -0.0005), (rp + 0.0005, rp + 0.0005, lp - 0.0015)),
               "grip": _box((-rg - 0.0005, -rg - 0.0005, lp + 0.0015), (rg + 0.0005, rg + 0.0005, hg + 0.0005))}
    return solid, regions


def drawer_handle():
    # Bar handle standing on its two posts. Handle frame: the drawer front is the plane z = 0, x runs
    # along the drawer's width, y is vertical once mounted (the fingers close along y).
    span, rb, rp, hp = 0.096, 0.006, 0.005, 0.032  # post spacing, bar/post radius, post height
    bar = rotate_z_to(revolve(_capsule_profile(0.128, rb, 0.005), segments=24, min_spacing=0.003), "x")
    bar = bar.translate((-0.064, 0.0, hp))
    posts = [revolve(_cat((0, 0), (0.009, 0), (0.009, 0.002), arc((rp + 0.003, 0.005), 0.003, -PI / 2, -PI, n=12),
                          (rp, hp), (0, hp)), segments=24, min_spacing=0.002).translate((x, 0.0, 0.0))
             for x in (-span / 2, span / 2)]
    # (regions get 1 mm of padding: grip and feet stay 1 mm apart)
    grip = _box((-0.066, -rb - 0.002, hp - rb), (0.066, rb + 0.002, hp + rb + 0.002))
    feet = [_box((x - 0.01, -0.01, 0), (x + 0.01, 0.01, hp - rb - 0.003)) for x in (-span / 2, span / 2)]
    regions = {"grip": grip, "left_foot": feet[0], "right_foot": feet[1],
               "bar": grip.copy(), "left_post": feet[0].copy(), "right_post": feet[1].copy()}  # old names
    return bar + posts[0] + posts[1], regions


def drawer_pull():
    # D-shaped pull: one round tube from a flat pad on the drawer front (z = 0) up a foot, through a
    # 90-degree bend, along the grip (parallel to the front) and back down; swept in one piece, so
    # there are no Boolean seams. Handle frame as for drawer_handle.
    xf, rt, rb, zg = 0.048, 0.0055, 0.014, 0.032  # foot x, tube radius, bend radius, grip height
    rp, tp, f = 0.010, 0.002, 0.003  # pad radius, pad thickness, pad-to-tube fillet radius
    a, b, g = zg - rb, PI / 2 * rb, 2 * (xf - rb)  # lengths of foot, bend, grip along the centerline
    length = 2 * (a + b) + g

    def half(s):  # left half of the centerline: foot up, bend, grip towards x = 0
        th = np.clip((s - a) / rb, 0, PI / 2)
        up, bend = s <= a, (s > a) & (s < a + b)
        c = np.zeros((len(s), 3))
        c[:, 0] = np.where(up, -xf, np.where(bend, -xf + rb - rb * np.cos(th), -xf + rb + s - a - b))
        c[:, 2] = np.where(up, s, np.where(bend, a + rb * np.sin(th), zg))
        t = np.zeros((len(s), 3))
        t[:, 0] = np.where(up, 0.0, np.where(bend, np.sin(th), 1.0))
        t[:, 2] = np.where(up, 1.0, np.where(bend, np.cos(th), 0.0))
        return c, t

    def path(s):
        right = s > length / 2
        c, t = half(np.where(right, length - s, s))
        c[right, 0] *= -1  # mirror in x; the tangent of the mirrored, reversed curve is (tx, 0, -tz)
        t[right, 2] *= -1
        return c, t

    prof = _cat((0, 0), (rp, 0), (rp, tp), arc((rt + f, tp + f), f, -PI / 2, -PI, n=12),
                arc((rt + f, length - tp - f), f, PI, PI / 2, n=12), (rp, length - tp), (rp, length), (0, length))
    solid = sweep_profile(prof, path, (0.0, 1.0, 0.0), segments=24, min_spacing=0.001)
    # (regions get 1 mm of padding: the grip ends where the bends begin, the feet 3 mm further out)
    regions = {"grip": _box((-(xf - rb), -rt, zg - rt), (xf - rb, rt, zg + rt)),
               "left_foot": _box((-xf - rp, -rp, 0), (-xf + rp, rp, zg - rt - 0.003)),
               "right_foot": _box((xf - rp, -rp, 0), (xf + rp, rp, zg - rt - 0.003))}
    return solid, regions


BUILDERS = {f.__name__: f for f in (mug, bottle, bowl, can, cup, screwdriver, hammer, sugar_box,
                                    spray_bottle, banana, plug, drawer_handle, usb_plug,
                                    round_peg, drawer_pull)}

# Plugs for the insertion task: connector length (m, from the tip at z = 0) and the height (m) of the
# point between the fingertips in the nominal grip.
INSERTION = {
    "usb_plug": {"head_length": 0.012, "grip_height": 0.030},
    "round_peg": {"head_length": 0.012, "grip_height": 0.030},
}

# Drawer handles for the drawer task, in the frame get_object returns (after normalization: z = 0 is
# the mounting plane on the drawer front, x along the drawer's width, y vertical once mounted, x/y
# centered): the grasp point (m), the center of the grip tube's cross-section at the middle of the
# grip, and the grip tube's radius (m). The fingers close along y around it.
DRAWER = {
    "drawer_handle": {"grasp": [0.0, 0.0, 0.032], "grip_radius": 0.006},
    "drawer_pull": {"grasp": [0.0, 0.0, 0.032], "grip_radius": 0.0055},
}

DESCRIPTIONS = {
    "mug": "a ceramic coffee mug with a round handle, about 8 cm wide and 10 cm tall",
    "bottle": "a plastic drink bottle with a narrow neck and a screw cap, about 22 cm tall",
    "bowl": "a shallow round kitchen bowl with a thin wall, 16 cm across",
    "can": "a closed food can (soup-can size), 6.6 cm across and 12 cm tall",
    "cup": "a tapered drinking cup without a handle, 10 cm tall",
    "screwdriver": "a screwdriver lying on the table: a thick handle and a thin steel shaft",
    "hammer": "a hammer lying on the table: a long handle and a cylindrical head",
    "sugar_box": "a cardboard sugar box (YCB size 9 x 4.5 x 17 cm) standing upright",
    "spray_bottle": "a spray bottle with a trigger and a nozzle on top of a round body",
    "banana": "a banana lying on the table, a curved elongated fruit",
    "plug": "a USB-like plug lying on the table: a grip body and a flat metal head to insert",
    "usb_plug": "a USB-like plug held upright for insertion: a flat metal connector head below a grip body",
    "round_peg": "a round peg held upright for insertion: a cylindrical pin below a wider cylindrical grip",
    "drawer_handle": "a bar-shaped drawer handle on two posts, mounted on a drawer front",
    "drawer_pull": "a D-shaped drawer pull: one round bent tube with two feet, mounted on a drawer front",
}
