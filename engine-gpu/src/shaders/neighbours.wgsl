// ---- neighbour rebuild: dispatched every step, a no-op unless a grain moved half a skin ----
//
// `drift` (or the host, after an insertion) sets ctl[0]; the rebuild kernels read it and the
// step's `forces` resets it (counting the rebuild), so no kernel of its own decides.

fn rebuilding() -> bool {
    return atomicLoad(&ctl[0]) != 0u;
}

@compute @workgroup_size(WG)
fn bin(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (!rebuilding() || i >= P.n || !alive(i)) {
        return;
    }
    let c = cell_index(cell[i].xyz);
    binned[i] = c;
    let slot = atomicAdd(&binn[c], 1u);
    if (slot < BIN) {
        bins[c * BIN + slot] = i;
    } else {
        atomicAdd(&ctl[3], 1u);
    }
}

// Appends to grain i's list (`count` long) the grains binned in cell `c` within its reach
// (the two radii and the skin); past CAP, counts an overflow.
fn gather_cell(i: u32, c: u32, list: ptr<function, array<u32, CAP>>, count: ptr<function, u32>) {
    let ri = off[i].w;
    let skin = P.misc.z;
    let m = min(atomicLoad(&binn[c]), BIN);
    for (var s = 0u; s < m; s++) {
        let j = bins[c * BIN + s];
        if (j == i) {
            continue;
        }
        let d = rel(i, j);
        let reach = ri + off[j].w + skin;
        if (dot(d, d) < reach * reach) {
            if (*count < CAP) {
                (*list)[*count] = j;
                *count += 1u;
            } else {
                atomicAdd(&ctl[2], 1u);
            }
        }
    }
}

// Grain i's neighbours within its reach from the 27 cells around its own (periodic axes
// wrapped), in the bins' order; returns how many were listed.
fn gather_neighbours(i: u32, list: ptr<function, array<u32, CAP>>) -> u32 {
    var count = 0u;
    let ci = cell[i].xyz;
    for (var dz = -1; dz <= 1; dz++) {
        let z = ci.z + dz;
        if (z < 0 || z >= P.dims.z) {
            continue;
        }
        for (var dy = -1; dy <= 1; dy++) {
            var y = ci.y + dy;
            if ((P.dims.w & 2) != 0) {
                y = (y + P.dims.y) % P.dims.y;
            } else if (y < 0 || y >= P.dims.y) {
                continue;
            }
            for (var dx = -1; dx <= 1; dx++) {
                var x = ci.x + dx;
                if ((P.dims.w & 1) != 0) {
                    x = (x + P.dims.x) % P.dims.x;
                } else if (x < 0 || x >= P.dims.x) {
                    continue;
                }
                gather_cell(i, u32(x + P.dims.x * (y + P.dims.y * z)), list, &count);
            }
        }
    }
    return count;
}

// Sorts the list by index: the gather order does not depend on the bins' fill order.
fn sort_by_index(list: ptr<function, array<u32, CAP>>, count: u32) {
    for (var a = 1u; a < count; a++) {
        let v = (*list)[a];
        var b = a;
        while (b > 0u && (*list)[b - 1u] > v) {
            (*list)[b] = (*list)[b - 1u];
            b--;
        }
        (*list)[b] = v;
    }
}

// Writes grain i's new list into the build's copy (`nbr2`, `spr2`), carrying the springs of
// pairs that were already listed (both lists are sorted). A grain inserted since the last
// build starts without history: its slot's old list and the springs others hold for the slot
// belonged to a removed grain.
fn carry_springs(i: u32, list: ptr<function, array<u32, CAP>>, count: u32) {
    let fresh = disp[i].w != 0.0;
    if (fresh) {
        for (var h = 0u; h < wall_words(); h++) {
            walls[slot(i, h)] = vec4<f32>(0.0);
        }
    }
    let old_count = select(nbn[i], 0u, fresh);
    var k = 0u;
    for (var a = 0u; a < count; a++) {
        let j = (*list)[a];
        while (k < old_count && nbr[slot(i, k)] < j) {
            k++;
        }
        var s = vec4<f32>(0.0);
        var r = vec4<f32>(0.0);
        if (k < old_count && nbr[slot(i, k)] == j && disp[j].w == 0.0) {
            s = spr[slot(i, k)];
            if (epsd()) {
                r = spr[slot(i, CAP + k)];
            }
        }
        nbr2[slot(i, a)] = j;
        spr2[slot(i, a)] = s;
        if (epsd()) {
            spr2[slot(i, CAP + a)] = r;
        }
    }
}

// Each grain's new neighbour list, sorted, with the springs it carries on.
@compute @workgroup_size(WG)
fn build(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (!rebuilding() || i >= P.n) {
        return;
    }
    var list: array<u32, CAP>;
    var count = 0u;
    if (alive(i)) {
        count = gather_neighbours(i, &list);
    }
    sort_by_index(&list, count);
    carry_springs(i, &list, count);
    nbn[i] = count; // its old count was read above; `commit` reads the new one
}

@compute @workgroup_size(WG)
fn commit(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    if (!rebuilding() || i >= P.n) {
        return;
    }
    disp[i] = vec4<f32>(0.0);
    // Empty the bins for the next rebuild (`build` has read them): each slot clears the cell
    // it was binned in. A slot whose grain was removed or never binned clears a cell that is
    // empty or cleared anyway, so the grid's cells cost nothing.
    atomicStore(&binn[binned[i]], 0u);
    let count = nbn[i];
    for (var a = 0u; a < count; a++) {
        nbr[slot(i, a)] = nbr2[slot(i, a)];
        spr[slot(i, a)] = spr2[slot(i, a)];
        if (epsd()) {
            spr[slot(i, CAP + a)] = spr2[slot(i, CAP + a)];
        }
    }
}
