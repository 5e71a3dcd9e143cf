#!/usr/bin/python3
"""Writes demo_urban.json: the bundled scenario that exercises every stage of the sensor model.

An urban street along the map's x axis, 10 s at 10 Hz. The ego drives at 8 m/s in the right
lane (y = 0). Two lanes each way: ours at y = 0 and 3.5, the opposite ones at 7 and 10.5; a
parking strip at y = -3.5 and a sidewalk at y = -6.5. A cross street at x = 110.
  - lead car ahead in our lane; a car overtaking us in the left lane;
  - an oncoming truck, and an oncoming car that passes us and leaves the 70 m range behind;
  - a pedestrian walking on the sidewalk behind a parked truck: hidden for a while, then seen;
  - two pedestrians crossing each other on a crosswalk at x = 95; a cyclist we overtake;
  - a car crossing on the cross street; a parked van; a pedestrian waiting at a bus stop.
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


def mover(oid, cls, t0, t1, x0, y0, vx, vy, ax=0.0, ay=0.0, material=None):
    """Constant acceleration from (x0, y0) at t0 to t1, keyframes every second."""
    h = SIZES[cls][2] / 2
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


def parked(oid, cls, x, y, heading_deg=0.0):
    return {"id": oid, "class": cls, "size": SIZES[cls],
            "states": [state(0.0, x, y, SIZES[cls][2] / 2, 0.0, 0.0, heading_deg)]}


def line(oid, kind, y, x0=-60.0, x1=200.0, gap=None):
    if gap is None:
        return [{"id": oid, "type": kind, "points": [[x0, y], [x1, y]]}]
    # Interrupted at the cross street [gap0, gap1].
    return [{"id": oid, "type": kind, "points": [[x0, y], [gap[0], y]]},
            {"id": oid + 100, "type": kind, "points": [[gap[1], y], [x1, y]]}]


def main():
    objects = [
        mover(1, "Car", 0, 10, 28.0, 0.0, 8.0, 0.0, ax=-0.3),          # lead car, slowly braking
        mover(2, "Car", 0, 10, -18.0, 3.5, 11.0, 0.0, ax=0.4),         # overtakes us on the left
        mover(3, "Truck", 0, 10, 95.0, 7.0, -7.0, 0.0),                # oncoming truck
        mover(4, "Car", 0, 10, 40.0, 10.5, -12.0, 0.0),                # oncoming, leaves range behind
        parked(5, "Truck", 45.0, -3.5),                                # parked truck (the occluder)
        mover(6, "Pedestrian", 0, 10, 62.0, -6.5, -1.3, 0.0),          # hidden behind the truck for a while
        mover(7, "Pedestrian", 1, 10, 95.0, -6.0, 0.0, 1.4),           # crossing northwards
        mover(8, "Pedestrian", 1, 10, 95.8, 13.0, 0.0, -1.4),          # crossing southwards
        mover(9, "Cyclist", 0, 10, 22.0, -2.2, 4.5, 0.0),              # overtaken by us
        mover(10, "Car", 2, 10, 110.0, -45.0, 0.0, 10.0),              # crossing on the cross street
        parked(11, "Van", 20.0, -3.5),
        parked(12, "Pedestrian", 30.0, -7.2, 90.0),                    # waiting at a bus stop
        mover(13, "Cyclist", 0, 10, 70.0, 8.0, -5.0, 0.0),             # oncoming cyclist
    ]
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
    }
    out = os.path.join(os.path.dirname(os.path.abspath(__file__)), "demo_urban.json")
    with open(out, "w") as f:
        json.dump(scenario, f, indent=1)
        f.write("\n")
    print("wrote", out)


if __name__ == "__main__":
    main()
