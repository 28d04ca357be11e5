#!/usr/bin/env python3
"""Few-grain side-by-side probes of repose and LIGGGHTS 3.8 with the funnel test's contact laws
(the `default` aor preset with rolling_model=epsd, damping_law=edem_formula). See README.md.

    python3 probes.py PROBE [PROBE ...] [--out DIR]

PROBE: slide drop impact pp_collide pp_roll pp_push tetra column drop_column funnel (all by
default). Each probe writes DIR/PROBE/{repose.json, in.liggghts, data.liggghts, plate.stl} and
the two time series DIR/PROBE/{repose,liggghts}.txt (`t id x y z vx vy vz wx wy wz`), then
prints a summary of both. Environment: PROBE_BIN (the repose probe example binary, built by
`cargo build --release -p repose-engine --example probe`), LIGGGHTS (liggghts), WALL_EXTRA
(appended to the wall/gran line, e.g. "limitForce on"), RIG (the directory of base.stl and
funnel.stl for the funnel probe), SEED (the lattice jitter), FUNNEL_LAYERS, FUNNEL_TIME.
"""
import json
import math
import os
import random
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
R = 0.001
SOIL = dict(name="soil", density=2664.0, youngs_modulus=3.67e6, poisson=0.36)
STEEL = dict(name="steel", density=7850.0, youngs_modulus=2.1e11, poisson=0.30)
SS = dict(restitution=0.45, static_friction=0.442, rolling_friction=0.14)
ST = dict(restitution=0.40, static_friction=0.305, rolling_friction=0.50)
STST = dict(restitution=0.5, static_friction=0.3, rolling_friction=0.01)
ETA_R = 0.3
# Extra wall/gran model settings, e.g. WALL_EXTRA="limitForce on" (in.funnel has none; LIGGGHTS
# takes it only at the end of the fix line, after the meshes).
WALL_EXTRA = os.environ.get("WALL_EXTRA", "")
G = 9.81


def rayleigh_time(radius, m):
    shear = m["youngs_modulus"] / (2.0 * (1.0 + m["poisson"]))
    return math.pi * radius * math.sqrt(m["density"] / shear) / (0.1631 * m["poisson"] + 0.8766)


DT = 0.2 * rayleigh_time(R, SOIL)
MASS = SOIL["density"] * 4.0 / 3.0 * math.pi * R ** 3


def grain(x, y, z, v=(0, 0, 0), w=(0, 0, 0), frozen=False):
    return dict(position=[x, y, z], velocity=list(v), angular_velocity=list(w), frozen=frozen)


def probes():
    """name -> (grains, duration s, print interval s, plate?)"""
    p = {}
    # 1. One grain on the plate, sliding at 0.1 m/s without spin (starts just touching).
    p["slide"] = ([grain(0.0031, 0.0017, R, v=(0.1, 0, 0))], 0.08, 0.0005, True)
    # 3. One grain dropped from 3 mm above contact.
    p["drop"] = ([grain(0.0031, 0.0017, R + 0.003)], 0.08, 0.0002, True)
    # 3b. One grain hitting the plate at 1.43 m/s (the fall from the funnel outlet, 105 mm).
    p["impact"] = ([grain(0.0031, 0.0017, R + 1e-5, v=(0, 0, -1.43))], 0.004, 0.00002, True)
    # 3c. Two free grains colliding head-on at 1.43 m/s relative speed (gravity acts on both).
    p["pp_collide"] = ([grain(0, 0, 0.01, v=(0.715, 0, 0)),
                        grain(2 * R + 1e-5, 0, 0.01, v=(-0.715, 0, 0))], 0.002, 0.00002, False)
    # 2a. A grain on top of a frozen grain, 0.2 R off the axis, at rest: rolls/slides off?
    p["pp_roll"] = ([grain(0, 0, 0, frozen=True),
                     grain(0.2 * R, 0, math.sqrt((2 * R) ** 2 - (0.2 * R) ** 2) - 1e-6)],
                    0.08, 0.0005, False)
    # 2b. A grain on top of a frozen grain, on the axis, pushed sideways at 0.05 m/s.
    p["pp_push"] = ([grain(0, 0, 0, frozen=True), grain(0, 0, 2 * R - 1e-6, v=(0.05, 0, 0))],
                    0.08, 0.0005, False)
    # 2c. A tetrahedron on the plate: three touching grains and one on top. Holds or spreads?
    s = 2 * R
    base = [(0.0, 0.0), (s, 0.0), (s / 2, s * math.sqrt(3) / 2)]
    cx, cy = s / 2, s * math.sqrt(3) / 6
    top_z = R + math.sqrt((2 * R) ** 2 - (s / math.sqrt(3)) ** 2)
    p["tetra"] = ([grain(x + 0.0031, y + 0.0017, R) for x, y in base]
                  + [grain(cx + 0.0031, cy + 0.0017, top_z)], 0.15, 0.001, True)
    # 4. A column of grains (a jittered cubic lattice, 7 x 7 x 10 = 490) dropped on the plate.
    rng = random.Random(int(os.environ.get("SEED", "5")))
    cells = []
    a = 2.2 * R
    for k in range(10):
        for j in range(7):
            for i in range(7):
                cells.append(grain((i - 3) * a + rng.uniform(-0.05, 0.05) * R + 0.0011,
                                   (j - 3) * a + rng.uniform(-0.05, 0.05) * R + 0.0007,
                                   R + 0.0002 + k * a + rng.uniform(-0.05, 0.05) * R))
    p["column"] = (cells, 0.6, 0.05, True)
    # 4b. The same column 100 mm up (it lands at ~1.4 m/s, like the funnel's stream).
    p["drop_column"] = ([dict(g, position=[g["position"][0], g["position"][1],
                                          g["position"][2] + 0.1]) for g in cells],
                        0.7, 0.05, True)
    # 5. The real rig (base.stl and funnel.stl from `repose aor --export-stl`, RIG env): a disc
    # of grains (jittered lattice, 2 layers) in the factory's region above the funnel rim,
    # moving down at 0.5 m/s, poured through the funnel onto the plate.
    rim = 0.105 + 0.04
    disc = []
    for k in range(FUNNEL_LAYERS):
        for j in range(-9, 10):
            for i in range(-9, 10):
                x, y = i * a + rng.uniform(-0.05, 0.05) * R, j * a + rng.uniform(-0.05, 0.05) * R
                if math.hypot(x, y) < 0.02:
                    disc.append(grain(x, y, rim + 2 * R + k * a + rng.uniform(-0.05, 0.05) * R,
                                      v=(0, 0, -0.5)))
    p["funnel"] = (disc, FUNNEL_TIME, 0.05, "rig")
    return p


FUNNEL_LAYERS = int(os.environ.get("FUNNEL_LAYERS", "2"))
FUNNEL_TIME = float(os.environ.get("FUNNEL_TIME", "0.8"))
RIG = os.environ.get("RIG", "/tmp/rig")  # `repose aor ... --export-stl /tmp/rig` (README)
PLATE_HALF = 0.1


def write_plate(path):
    h = PLATE_HALF
    tris = [((-h, -h, 0), (h, -h, 0), (h, h, 0)), ((-h, -h, 0), (h, h, 0), (-h, h, 0))]
    with open(path, "w") as f:
        f.write("solid plate\n")
        for t in tris:
            f.write(" facet normal 0 0 1\n  outer loop\n")
            for v in t:
                f.write("   vertex %.9e %.9e %.9e\n" % v)
            f.write("  endloop\n endfacet\n")
        f.write("endsolid plate\n")


def write_repose(d, grains, steps, every, plate):
    scene = {
        "materials": {
            "materials": [SOIL, STEEL],
            "interactions": [dict(a="soil", b="soil", **SS), dict(a="soil", b="steel", **ST),
                             dict(a="steel", b="steel", **STST)],
            "damping_law": "edem_formula",
        },
        "geometries": ([{"name": "plate", "material": "steel",
                         "mesh": {"kind": "stl", "path": os.path.join(d, "plate.stl"),
                                  "scale": 1.0}}] if plate is True else
                       [{"name": n, "material": "steel",
                         "mesh": {"kind": "stl", "path": os.path.join(RIG, n + ".stl"),
                                  "scale": 1.0}} for n in ("base", "funnel")] if plate else []),
        "domain": {"min": [-0.16, -0.16, -0.05], "max": [0.16, 0.16, 0.17],
                   "periodic_x": False, "periodic_y": False},
        # A never-inserted list (prepare wants particles; the probe adds its own grains).
        "particles": [{"material": "soil", "time": 1e9,
                       "particles": [{"center": [0.09, 0.09, 0.09], "radius": R}]}],
        "duration": steps * DT,
        "time_step": {"fixed": DT},
        "rolling_model": {"model": "elastic_plastic_spring_dashpot", "viscous_damping": ETA_R},
    }
    probe = {"scene": scene,
             "particles": [dict(material="soil", radius=R, **g) for g in grains],
             "steps": steps, "print_every": every}
    with open(os.path.join(d, "repose.json"), "w") as f:
        json.dump(probe, f, indent=1)


def write_liggghts(d, grains, steps, every, plate):
    with open(os.path.join(d, "data.liggghts"), "w") as f:
        f.write("probe\n\n%d atoms\n2 atom types\n\n" % len(grains))
        f.write("-0.16 0.16 xlo xhi\n-0.16 0.16 ylo yhi\n-0.05 0.17 zlo zhi\n\nAtoms\n\n")
        for i, g in enumerate(grains):
            f.write("%d 1 %.9e %.6f %.12e %.12e %.12e\n"
                    % (i + 1, 2 * R, SOIL["density"], *g["position"]))
        f.write("\nVelocities\n\n")
        for i, g in enumerate(grains):
            f.write("%d %.9e %.9e %.9e %.9e %.9e %.9e\n"
                    % (i + 1, *g["velocity"], *g["angular_velocity"]))
    frozen = [str(i + 1) for i, g in enumerate(grains) if g["frozen"]]
    mobile = [str(i + 1) for i, g in enumerate(grains) if not g["frozen"]]

    def pairs(key):
        return "%g %g %g %g" % (SS[key], ST[key], ST[key], STST[key])

    lines = f"""atom_style granular
atom_modify map array
boundary f f f
newton off
communicate single vel yes
units si
soft_particles yes
hard_particles yes
read_data {d}/data.liggghts
neighbor {0.5 * R} bin
neigh_modify delay 0
timestep {DT!r}
fix m1 all property/global youngsModulus peratomtype {SOIL['youngs_modulus']} {STEEL['youngs_modulus']}
fix m2 all property/global poissonsRatio peratomtype {SOIL['poisson']} {STEEL['poisson']}
fix m3 all property/global coefficientRestitution peratomtypepair 2 {pairs('restitution')}
fix m4 all property/global coefficientFriction peratomtypepair 2 {pairs('static_friction')}
fix m5 all property/global coefficientRollingFriction peratomtypepair 2 {pairs('rolling_friction')}
fix m6 all property/global coefficientRollingViscousDamping peratomtypepair 2 {ETA_R} {ETA_R} {ETA_R} {ETA_R}
pair_style gran model hertz tangential history rolling_friction epsd limitForce on
pair_coeff * *
"""
    if plate == "rig":
        lines += f"""fix base all mesh/surface file {RIG}/base.stl type 2 curvature_tolerant yes
fix funnel all mesh/surface file {RIG}/funnel.stl type 2 curvature_tolerant yes
fix walls all wall/gran model hertz tangential history rolling_friction epsd mesh n_meshes 2 meshes base funnel {WALL_EXTRA}
"""
    elif plate:
        lines += f"""fix base all mesh/surface file {d}/plate.stl type 2 curvature_tolerant yes
fix walls all wall/gran model hertz tangential history rolling_friction epsd mesh n_meshes 1 meshes base {WALL_EXTRA}
"""
    lines += f"group mobile id {' '.join(mobile)}\n"
    if frozen:
        lines += f"group frozen id {' '.join(frozen)}\n"
    lines += f"""fix grav all gravity {G} vector 0.0 0.0 -1.0
fix integr mobile nve/sphere
dump d all custom {every} {d}/liggghts.dump id x y z vx vy vz omegax omegay omegaz
dump_modify d sort id
thermo 1000
run {steps}
"""
    with open(os.path.join(d, "in.liggghts"), "w") as f:
        f.write(lines)


def read_liggghts_dump(path, out):
    rows = []
    step = None
    with open(path) as f:
        it = iter(f)
        for line in it:
            if line.startswith("ITEM: TIMESTEP"):
                step = int(next(it))
            elif line.startswith("ITEM:"):
                continue
            else:
                parts = line.split()
                if len(parts) == 10 and step is not None:
                    rows.append("%.7e %s" % (step * DT, " ".join(parts)))
    with open(out, "w") as f:
        f.write("\n".join(rows) + "\n")


def load(path):
    """{t: {id: [x y z vx vy vz wx wy wz]}}"""
    data = {}
    for line in open(path):
        p = line.split()
        if len(p) != 11:
            continue
        t = round(float(p[0]) / DT)
        data.setdefault(t, {})[int(p[1])] = [float(v) for v in p[2:]]
    return data


def summarize(name, data):
    steps = sorted(data)
    last = data[steps[-1]]
    out = []
    if name in ("slide", "drop"):
        g = [(s * DT, data[s][1]) for s in steps]
        stop = None
        for t, s in g:
            speed = math.sqrt(s[3] ** 2 + s[4] ** 2 + s[5] ** 2)
            if stop is None and t > 0.001 and speed < 1e-4 and abs(s[7]) < 0.1:
                stop = t
        x0 = g[0][1][0]
        f = g[-1][1]
        out.append(f"final x-x0 {1e3 * (f[0] - x0):.4f} mm, z {1e6 * f[2]:.3f} um "
                   f"(overlap {1e6 * (R - f[2]):.3f} um), vx {f[3]:.3e}, vz {f[5]:.3e}, "
                   f"wy {f[7]:.3e}, stop (|v|<1e-4, |w|<0.1) at {stop}")
        if name == "slide":
            for t, s in g:
                if abs(s[3] - s[7] * R) < 1e-4 * 0.1 and t > 0:
                    out.append(f"rolling (vx = wy R) from t = {1e3 * t:.2f} ms, vx {s[3]:.4f}")
                    break
            for tt in (0.005, 0.01, 0.015, 0.02, 0.03, 0.04):
                s = min(g, key=lambda p: abs(p[0] - tt))
                out.append(f"  t {1e3 * s[0]:.1f} ms: x-x0 {1e3 * (s[1][0] - x0):.4f} mm, "
                           f"vx {s[1][3]:.5f}, wy R {s[1][7] * R:.5f}")
        if name == "drop":
            # first rebound: max z after first time vz > 0 and z > R
            up = [(t, s) for t, s in g if s[5] > 0]
            if up:
                t_up = up[0][0]
                after = [(t, s) for t, s in g if t >= t_up]
                z_apex = 0
                v_leave = None
                for t, s in after:
                    if s[2] >= R and v_leave is None:
                        v_leave = s[5]
                    if s[5] < 0 and s[2] > R:
                        break
                    z_apex = max(z_apex, s[2])
                h0 = 0.003
                out.append(f"first apex {1e3 * (z_apex - R):.4f} mm above contact (of 3 mm): "
                           f"e_eff = sqrt(h1/h0) = {math.sqrt(max(z_apex - R, 0) / h0):.4f}, "
                           f"speed leaving {v_leave} (impact {math.sqrt(2 * G * h0):.4f})")
    elif name == "impact":
        g = [(s * DT, data[s][1]) for s in steps]
        f = g[-1][1]
        out.append(f"after {1e3 * g[-1][0]:.1f} ms: vz {f[5]:.4f} m/s (e = {f[5] / 1.43:.4f}), "
                   f"vx {f[3]:.2e}, z-R {1e6 * (f[2] - R):.1f} um")
    elif name == "pp_collide":
        g = [(s * DT, data[s]) for s in steps]
        f = g[-1][1]
        out.append(f"after {1e3 * g[-1][0]:.1f} ms: relative vx {f[2][3] - f[1][3]:.4f} m/s "
                   f"(e = {(f[2][3] - f[1][3]) / 1.43:.4f})")
    elif name in ("pp_roll", "pp_push"):
        for tt in (0.005, 0.01, 0.02, 0.04, 0.08):
            s = min(steps, key=lambda k: abs(k * DT - tt))
            q = data[s][2]
            ang = math.degrees(math.atan2(math.hypot(q[0], q[1]), q[2]))
            out.append(f"  t {1e3 * s * DT:.1f} ms: top grain polar angle {ang:.3f} deg, "
                       f"x {1e3 * q[0]:.4f} mm z {1e3 * q[2]:.4f} mm, wy {q[7]:.3f}")
    elif name == "tetra":
        for tt in (0.0, 0.01, 0.02, 0.05, 0.1, 0.15):
            s = min(steps, key=lambda k: abs(k * DT - tt))
            d = data[s]
            xs = [d[i] for i in (1, 2, 3)]
            cx = sum(p[0] for p in xs) / 3
            cy = sum(p[1] for p in xs) / 3
            spread = sum(math.hypot(p[0] - cx, p[1] - cy) for p in xs) / 3
            out.append(f"  t {1e3 * s * DT:.0f} ms: base spread {1e3 * spread:.4f} mm "
                       f"(touching {1e3 * 2 * R / math.sqrt(3):.4f}), top z {1e3 * d[4][2]:.4f} mm")
    elif name == "funnel":
        for s in steps[:: max(1, len(steps) // 16)] + [steps[-1]]:
            d = data[s]
            pts = [p for p in d.values() if p[2] > -0.01]
            below = [p for p in pts if p[2] < 0.105]
            low = [p for p in pts if p[2] < 0.02]
            rs = sorted(math.hypot(p[0], p[1]) for p in low) or [0]
            ke = sum(0.5 * MASS * (p[3] ** 2 + p[4] ** 2 + p[5] ** 2) for p in pts) / len(pts)
            out.append(f"  t {s * DT:.3f} s: {len(pts)} grains, {len(below)} below the outlet, "
                       f"{len(low)} below 20 mm: r50 {1e3 * rs[len(rs) // 2]:.2f} r90 "
                       f"{1e3 * rs[int(0.9 * len(rs))]:.2f} rmax {1e3 * rs[-1]:.2f} mm, "
                       f"height {1e3 * (max([p[2] for p in low] or [0]) + R):.2f} mm, "
                       f"ke/(m g d) {ke / (MASS * G * 2 * R):.2e}")
    elif name in ("column", "drop_column"):
        for s in steps[:: max(1, len(steps) // 12)] + [steps[-1]]:
            d = data[s]
            pts = [p for p in d.values() if p[2] > -0.01]
            zs = sorted(p[2] for p in pts)
            rs = sorted(math.hypot(p[0] - 0.0011, p[1] - 0.0007) for p in pts)
            ke = sum(0.5 * MASS * (p[3] ** 2 + p[4] ** 2 + p[5] ** 2) for p in pts) / len(pts)
            out.append(f"  t {s * DT:.3f} s: height {1e3 * (zs[-1] + R):.2f} mm, r50 "
                       f"{1e3 * rs[len(rs) // 2]:.2f} r90 {1e3 * rs[int(0.9 * len(rs))]:.2f} "
                       f"rmax {1e3 * rs[-1]:.2f} mm, ke/(m g d) {ke / (MASS * G * 2 * R):.2e}")
    return out


def main():
    args = sys.argv[1:]
    out = "/tmp/peer-probes"
    if "--out" in args:
        i = args.index("--out")
        out = args[i + 1]
        del args[i:i + 2]
    binary = os.environ.get("PROBE_BIN", "target/release/examples/probe")
    liggghts = os.environ.get("LIGGGHTS", "liggghts")
    table = probes()
    for name in args or list(table):
        grains, duration, interval, plate = table[name]
        steps = round(duration / DT)
        every = max(1, round(interval / DT))
        d = os.path.abspath(os.path.join(out, name))
        os.makedirs(d, exist_ok=True)
        write_plate(os.path.join(d, "plate.stl"))
        write_repose(d, grains, steps, every, plate)
        write_liggghts(d, grains, steps, every, plate)
        with open(os.path.join(d, "repose.txt"), "w") as f:
            subprocess.run([binary, os.path.join(d, "repose.json")], stdout=f, check=True)
        subprocess.run([liggghts, "-in", os.path.join(d, "in.liggghts"), "-log",
                        os.path.join(d, "log.liggghts"), "-screen",
                        os.path.join(d, "screen.liggghts")], check=True)
        read_liggghts_dump(os.path.join(d, "liggghts.dump"), os.path.join(d, "liggghts.txt"))
        print(f"== {name}: {len(grains)} grains, {steps} steps of {DT:.6e} s")
        for engine in ("repose", "liggghts"):
            print(f" {engine}:")
            for line in summarize(name, load(os.path.join(d, engine + ".txt"))):
                print("  " + line)


if __name__ == "__main__":
    main()
