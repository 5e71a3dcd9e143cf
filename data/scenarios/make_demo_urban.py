#!/usr/bin/python3
"""Writes demo_urban.json: the bundled scenario that exercises every stage of the sensor model.

An urban street along the map's x axis, 10 s at 10 Hz. The ego drives at 8 m/s in the right
lane (y = 0). Two lanes each way: ours at y = 0 and 3.5, the opposite ones at 7 and 10.5; a
parking strip at y = -3.5 and sidewalks (12 cm slabs whose road-side faces are the kerbs) at
y = -5.25 .. -8.75 and 12.25 .. 15.75, lowered at the crosswalk (x = 93 .. 98). A cross street
at x = 104 .. 116.
  - lead car ahead in our lane; a car overtaking us in the left lane;
  - an oncoming truck, and an oncoming car that passes us and leaves the 70 m range behind;
  - a pedestrian walking on the sidewalk behind a parked truck: hidden for a while, then seen;
  - two pedestrians crossing each other on a crosswalk at x = 95; a cyclist we overtake;
  - a car crossing on the cross street (hidden by the corner buildings until it nears the
    junction); a parked van and parked cars along the parking strip (objects: a detector must
    find them); a pedestrian waiting at a bus stop.
Static scenery (sensor/scenery.h; never reported as objects, but it hides what is behind it and
returns points): buildings on both sides with gaps, front gardens behind fences and hedges,
terrain behind the building line, street trees, street lights, signs and a bus shelter.
Positions are box centres (z = height / 2 on the road at z = 0); keyframes use constant velocity
or constant acceleration, which the reader reproduces exactly (quintic Hermite).
Run: /usr/bin/python3 data/scenarios/make_demo_urban.py  (writes next to itself)
"""
import json
import math
import os

SIZES = {"Car": [4.5, 1.8, 1.5], "Van": [5.0, 2.0, 2.1], "Truck": [10.0, 2.5, 3.5],
         "Pedestrian": [0.6, 0.6, 1.8], "Cyclist": [1.8, 0.6, 1.7]}


def state(t, x, y, z, vx, vy, heading_deg, ax=0.0, ay=0.0):
    return {"t": round(t, 6), "position": [round(x, 6), round(y, 6), round(z, 6)],
            "velocity": [round(vx, 6), round(vy, 6), 0.0], "acceleration": [ax, ay, 0.0],
            "heading_deg": heading_deg}


KERB = 0.12  # sidewalk height, m: pedestrians on a sidewalk stand on it


def mover(oid, cls, t0, t1, x0, y0, vx, vy, ax=0.0, ay=0.0, material=None, base=0.0):
    """Constant acceleration from (x0, y0) at t0 to t1, keyframes every second."""
    h = base + SIZES[cls][2] / 2
    states = []
    n = max(1, int(round(t1 - t0)))
    for k in range(n + 1):
        dt = (t1 - t0) * k / n
        x = x0 + vx * dt + 0.5 * ax * dt * dt
        y = y0 + vy * dt + 0.5 * ay * dt * dt
        vxt, vyt = vx + ax * dt, vy + ay * dt
        heading = math.degrees(math.atan2(vyt, vxt)) if math.hypot(vxt, vyt) > 1e-6 else 0.0
        states.append(state(t0 + dt, x, y, h, vxt, vyt, round(heading, 6), ax, ay))
    obj = {"id": oid, "class": cls, "size": SIZES[cls], "states": states}
    if material:
        obj["material"] = material
    return obj


def parked(oid, cls, x, y, heading_deg=0.0, base=0.0):
    return {"id": oid, "class": cls, "size": SIZES[cls],
            "states": [state(0.0, x, y, base + SIZES[cls][2] / 2, 0.0, 0.0, heading_deg)]}


def line(oid, kind, y, x0=-60.0, x1=200.0, gap=None):
    if gap is None:
        return [{"id": oid, "type": kind, "points": [[x0, y], [x1, y]]}]
    # Interrupted at the cross street [gap0, gap1].
    return [{"id": oid, "type": kind, "points": [[x0, y], [gap[0], y]]},
            {"id": oid + 100, "type": kind, "points": [[gap[1], y], [x1, y]]}]


def box(cls, x0, x1, y0, y1, height, base=0.0, material=None):
    """An axis-aligned box over [x0, x1] x [y0, y1] standing on `base`."""
    e = {"kind": "box", "class": cls, "position": [(x0 + x1) / 2, (y0 + y1) / 2, base],
         "size": [x1 - x0, abs(y1 - y0), height]}
    if material:
        e["material"] = material
    return e


def wall(cls, points, width, height):
    return {"kind": "extrusion", "class": cls, "points": points, "width": width, "height": height}


def tree(x, y, crown=4.5, trunk=2.4):
    return {"kind": "tree", "position": [x, y, KERB], "trunk_diameter": 0.35, "trunk_height": trunk,
            "crown_diameter": crown, "crown_height": crown}


def pole(x, y, height=8.0, sign=None):
    e = {"kind": "pole", "position": [x, y, KERB], "height": height, "diameter": 0.2}
    if sign:
        e["sign"] = {"size": sign[0], "heading_deg": sign[1]}
    return e


def scenery():
    """Both sides of the street: (x0, x1, height, setback) per lot; a setback is a front garden
    (terrain) behind a fence or a hedge. Buildings are 12-15 m deep; gaps between them show the
    terrain behind the building line."""
    out = []
    sides = [(-1, -8.75, [(-70, -52, 12, 0), (-49, -31, 9, 4), (-27, -12, 15, 0), (-8, 10, 7, 5), (14, 33, 18, 0),
                          (37, 52, 10, 0), (56, 75, 13, 4), (80, 100, 16, 0), (120, 140, 12, 0), (144, 165, 9, 3)]),
             (1, 15.75, [(-70, -45, 10, 0), (-42, -20, 14, 0), (-16, 5, 8, 6), (9, 30, 20, 0), (34, 48, 11, 4),
                         (52, 70, 15, 0), (74, 100, 9, 5), (120, 138, 13, 0), (142, 170, 10, 0)])]
    for side, edge, lots in sides:
        far = edge + side * 50.0
        # Sidewalk slabs (kerb at the road edge), cut at the crosswalk and the cross street, the cross
        # street's own sidewalks, and terrain behind them.
        kerb = edge - side * 3.5
        for x0, x1 in [(-80, 93), (98, 104), (116, 200)]:
            out.append(box("sidewalk", x0, x1, kerb, edge, KERB))
        for x0, x1 in [(100.5, 104), (116, 119.5)]:
            out.append(box("sidewalk", x0, x1, edge, far, KERB))
        for x0, x1 in [(-80, 100.5), (119.5, 200)]:
            out.append(box("terrain", x0, x1, edge, far, 0.05))
        for k, (x0, x1, height, setback) in enumerate(lots):
            front = edge + side * (0.25 + setback)
            depth = 12.0 + 3.0 * (k % 2)
            out.append(box("building", x0, x1, front, front + side * depth, height))
            if setback:  # front garden: a fence on odd lots, a hedge on even ones, and a tree in it
                y = edge + side * 0.3
                if k % 2:
                    out.append(wall("fence", [[x0, y], [x1, y]], 0.05, 1.1))
                else:
                    out.append(wall("vegetation", [[x0 + 0.5, y + side * 0.4], [x1 - 0.5, y + side * 0.4]], 0.8, 1.4))
                out.append(tree((x0 + x1) / 2, edge + side * (0.3 + setback / 2), crown=min(5.0, setback + 1.0)))
    # Street trees near the kerbs every 10 m (none over the parked truck at x = 45, the bus stop at
    # x = 30, the crosswalk and the junction), street lights between them. Broad crowns from 2.7 m
    # up, clear of the parked van and cars.
    for x in range(-75, 175, 10):
        if not (24 <= x <= 52 or 86 <= x <= 122):
            out.append(tree(float(x), -5.9, crown=6.0, trunk=2.6))
        if not 86 <= x <= 122:
            out.append(tree(float(x) + 5, 12.9, crown=6.0, trunk=2.6))
    for x in [-52, -22, 8, 38, 68, 121, 151]:
        out.append(pole(float(x), -5.55))
    for x in [-37, -7, 23, 53, 83, 126, 156]:
        out.append(pole(float(x), 12.55))
    # Signs: speed limit for us, one for the oncoming traffic, a stop sign on the cross street, a
    # bus stop sign, and the bus shelter's back wall and roof behind the waiting pedestrian.
    out.append(pole(15.0, -5.55, 2.6, ([0.6, 0.6], 180.0)))
    out.append(pole(60.0, 12.55, 2.6, ([0.6, 0.6], 0.0)))
    out.append(pole(101.5, -9.5, 2.4, ([0.7, 0.7], -90.0)))
    out.append(pole(27.0, -5.55, 2.8, ([0.4, 0.5], 90.0)))
    out.append(box("other_structure", 28.0, 32.0, -8.35, -8.2, 2.4, base=KERB, material="metal"))
    out.append(box("other_structure", 28.0, 32.0, -8.35, -6.9, 0.1, base=KERB + 2.4, material="metal"))
    return out


def main():
    objects = [
        mover(1, "Car", 0, 10, 28.0, 0.0, 8.0, 0.0, ax=-0.3),          # lead car, slowly braking
        mover(2, "Car", 0, 10, -18.0, 3.5, 11.0, 0.0, ax=0.4),         # overtakes us on the left
        mover(3, "Truck", 0, 10, 95.0, 7.0, -7.0, 0.0),                # oncoming truck
        mover(4, "Car", 0, 10, 40.0, 10.5, -12.0, 0.0),                # oncoming, leaves range behind
        parked(5, "Truck", 45.0, -3.5),                                # parked truck (the occluder)
        mover(6, "Pedestrian", 0, 10, 62.0, -6.5, -1.3, 0.0, base=KERB),  # hidden behind the truck for a while
        mover(7, "Pedestrian", 1, 10, 95.0, -6.0, 0.0, 1.4),           # crossing northwards
        mover(8, "Pedestrian", 1, 10, 95.8, 13.0, 0.0, -1.4),          # crossing southwards
        mover(9, "Cyclist", 0, 10, 22.0, -2.2, 4.5, 0.0),              # overtaken by us
        mover(10, "Car", 2, 10, 110.0, -45.0, 0.0, 10.0),              # crossing on the cross street
        parked(11, "Van", 20.0, -3.5),
        parked(12, "Pedestrian", 30.0, -7.2, 90.0, base=KERB),         # waiting at a bus stop
        mover(13, "Cyclist", 0, 10, 70.0, 8.0, -5.0, 0.0),             # oncoming cyclist
    ]
    # Parked cars on the parking strip, clear of the van, the truck, the crosswalk and the junction.
    for i, x in enumerate([-40.0, -28.0, 6.0, 59.0, 66.0, 78.0, 124.0, 131.0, 147.0]):
        objects.append(parked(14 + i, "Car", x, -3.5))
    lanes = []
    gap = (104.0, 116.0)
    lanes += line(1, "road_edge", -1.75 - 3.5, gap=gap)  # kerb beyond the parking strip
    lanes += line(2, "solid", -1.75, gap=gap)            # right edge line of our lane
    lanes += line(3, "dashed", 1.75, gap=gap)            # between our two lanes
    lanes += line(4, "solid", 5.25, gap=gap)             # centre line
    lanes += line(5, "dashed", 8.75, gap=gap)
    lanes += line(6, "road_edge", 12.25, gap=gap)
    scenario = {
        "name": "demo_urban",
        "duration": 10.0,
        "rate_hz": 10.0,
        "sensor": {
            "mount": {"x": 0.0, "y": 0.0, "z": 1.73, "roll_deg": 0.0, "pitch_deg": 0.0, "yaw_deg": 0.0},
            "beams": "hdl64e",
            "columns": 1024,
            "fov": {"horizontal_deg": [-180.0, 180.0], "vertical_deg": [-25.0, 3.0]},
            "max_range": 70.0,
            "min_range": 1.0,
        },
        "ego": {"states": [state(0.0, 0.0, 0.0, 0.0, 8.0, 0.0, 0.0), state(10.0, 80.0, 0.0, 0.0, 8.0, 0.0, 0.0)]},
        "objects": objects,
        "lanes": lanes,
        "scenery": scenery(),
    }
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "demo_urban.json")
    with open(out, "w") as f:
        json.dump(scenario, f, indent=1)
        f.write("\n")
    print("wrote", out)


if __name__ == "__main__":
    main()
