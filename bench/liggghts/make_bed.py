#!/usr/bin/env python3
"""Write the initial jittered lattice of the repose bench bed as a LIGGGHTS data file and print
the derived case parameters (box, time step, settling step counts) as LIGGGHTS -var arguments.

Mirrors engine/src/bench.rs (settled_bed / bed_world) exactly, except for the random number
generator (Python's Mersenne twister instead of ChaCha8).

usage: make_bed.py N SEED OUT.data
"""
import math
import random
import sys

R = 1.0e-3                       # BED_RADIUS, mean radius (radii uniform in [0.9, 1.1] R)
RHO, E, NU = 2664.0, 3.67e6, 0.36  # MaterialSet::paper soil

n, seed, out = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3]
spacing = 2.2 * R * 1.1
side = max(math.ceil((2.0 * n) ** (1.0 / 3.0) - 1e-12), 4)
layers = -(-n // (side * side))
width = side * spacing
height = (layers + 2.0) * spacing
zlo, zhi = -0.5 * spacing, height + spacing

# Time step: 20 % of the Rayleigh time of the smallest particle (0.9 R), as bench.rs.
g_mod = E / (2.0 * (1.0 + NU))
t_rayleigh = math.pi * 0.9 * R * math.sqrt(RHO / g_mod) / (0.1631 * NU + 0.8766)
dt = 0.2 * t_rayleigh

# Settling schedule of bench.rs: run 2 * fall, then in chunks of 100 steps until the fastest
# particle is below 1 mm/s, at most until 10 * fall.
drop = layers * (spacing - 2.0 * R)
fall = math.sqrt(2.0 * drop / 9.81)
nfall = math.ceil(2.0 * fall / dt)
nmax = math.ceil(10.0 * fall / dt)

rng = random.Random(seed)
atoms = []
placed = 0
for z in range(layers):
    for y in range(side):
        for x in range(side):
            if placed == n:
                break
            jx, jy, jz = (rng.uniform(-0.05, 0.05) * spacing for _ in range(3))
            cx = (x + 0.5) * spacing + jx
            cy = (y + 0.5) * spacing + jy
            cz = (z + 0.5) * spacing + R + jz
            r = R * rng.uniform(0.9, 1.1)
            placed += 1
            atoms.append((placed, 1, 2.0 * r, RHO, cx % width, cy % width, cz))

with open(out, "w") as f:
    f.write(f"repose bench bed, {n} spheres, seed {seed}\n\n{n} atoms\n2 atom types\n\n")
    f.write(f"0 {width!r} xlo xhi\n0 {width!r} ylo yhi\n{zlo!r} {zhi!r} zlo zhi\n\nAtoms\n\n")
    for a in atoms:
        f.write("%d %d %.10e %.1f %.10e %.10e %.10e\n" % a)

print(f"-var N {n} -var W {width!r} -var ZLO {zlo!r} -var ZHI {zhi!r} -var DT {dt!r} "
      f"-var NFALL {nfall} -var NMAX {nmax} -var SKIN {0.2 * 2.0 * 1.1 * R!r}")
