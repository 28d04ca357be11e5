// The contact laws: Hertz-Mindlin with the tangential spring and the Coulomb cap, EPSD's
// rolling spring, JKR's and the linear cohesion, and a particle pair's whole contact.

fn rotate_into_tangent_plane(s: vec3<f32>, n: vec3<f32>) -> vec3<f32> {
    let old_len2 = dot(s, s);
    let along = dot(n, s);
    let projected = s - n * along;
    if (along * along <= 1e-12 * old_len2) {
        return projected;
    }
    let new_len2 = dot(projected, projected);
    if (new_len2 > 0.0) {
        return projected * sqrt(old_len2 / new_len2);
    }
    return vec3<f32>(0.0);
}

struct Hertz {
    force: vec3<f32>,
    normal_force: f32,
    // the tangent normal stiffness 2 E* sqrt(R* overlap)
    stiffness: f32,
    spring: vec3<f32>,
}

fn hertz_mindlin(c: PairC, r_star: f32, m_star: f32, overlap: f32, n: vec3<f32>,
                 vrel: vec3<f32>, spring_in: vec3<f32>) -> Hertz {
    let srd = sqrt(r_star * overlap);
    let sn = 2.0 * c.a.x * srd;
    let st = 8.0 * c.a.y * srd;
    let normal_dashpot = -DAMPING_FACTOR * c.a.z * sqrt(sn * m_star);
    let tangential_dashpot = normal_dashpot * c.a.w;
    let vn = dot(vrel, n);
    let fn_elastic = (2.0 / 3.0) * sn * overlap;
    let fn_damping = -normal_dashpot * vn;
    let normal_force = max(fn_elastic + fn_damping, 0.0);
    let vt = vrel - n * vn;
    var s = rotate_into_tangent_plane(spring_in, n) + vt * P.misc.x;
    var ft = -s * st - vt * tangential_dashpot;
    let cap = c.b.x * normal_force;
    let ft2 = dot(ft, ft);
    if (ft2 > cap * cap) {
        if (ft2 > 0.0) {
            ft = ft * (cap / sqrt(ft2));
        }
        if (st > 0.0) {
            s = ft * (-1.0 / st);
        } else {
            s = vec3<f32>(0.0);
        }
    }
    var h: Hertz;
    h.force = n * normal_force + ft;
    h.normal_force = normal_force;
    h.stiffness = sn;
    h.spring = s;
    return h;
}

// EPSD rolling (the CPU engine's rolling model `ElasticPlasticSpringDashpot`): the rolling
// spring per contact, its words after the tangential springs (`spr` slot CAP + k, `walls`
// slot 2 WCAP + h).
fn epsd() -> bool {
    return EPSD && P.misc2.y == 0.0;
}

// Words of a grain's triangle histories: normal and spring, and the rolling spring with EPSD.
fn wall_words() -> u32 {
    return select(2u, 3u, epsd()) * WCAP;
}

struct Rolling {
    torque: vec3<f32>,
    spring: vec3<f32>,
}

// The EPSD rolling torque (the CPU engine's `epsd_rolling_torque`): the spring follows the
// relative rolling velocity at stiffness kr up to the plastic torque, with a dashpot while
// elastic; kr = 2.25 (2/3 stiffness) mu_r^2 R*^2 (`epsd_rolling_stiffness`).
fn epsd_rolling(n: vec3<f32>, w_rel: vec3<f32>, stiffness: f32, mu_r: f32, r_star: f32,
                normal_force: f32, inertia: f32, spring_in: vec3<f32>) -> Rolling {
    let kr = 2.25 * (stiffness * (2.0 / 3.0)) * mu_r * mu_r * r_star * r_star;
    let max_torque = mu_r * r_star * normal_force;
    let damping = P.misc2.z * 2.0 * sqrt(inertia * kr);
    let omega_r = w_rel - n * dot(n, w_rel);
    var s = rotate_into_tangent_plane(spring_in, n) - omega_r * (kr * P.misc.x);
    var out: Rolling;
    let len2 = dot(s, s);
    if (len2 > max_torque * max_torque) {
        s = s * (max_torque / sqrt(len2));
        out.torque = s;
    } else {
        out.torque = s - omega_r * damping;
    }
    out.spring = s;
    return out;
}

// s = sqrt(a / a0) on JKR's stable branch for D = overlap R* / a0^2: the largest root of
// s^4 - s = D (the CPU engine's `jkr_root`): Newton from 1 + D^(1/4), which decreases onto it.
fn jkr_root(d: f32) -> f32 {
    var s = 1.0;
    if (d > 0.0) {
        s = 1.0 + sqrt(sqrt(d));
    }
    for (var k = 0; k < 40; k++) {
        let g = s * s * s * s - s - d;
        let slope = 4.0 * s * s * s - 1.0;
        if (g <= 0.0 || slope <= 0.0) {
            break;
        }
        let step = g / slope;
        s -= step;
        if (step <= 1e-7 * s) {
            break;
        }
    }
    return s;
}

// JKR's contact length a0^2 / R* for the pair (a0^3 = 2 pi gamma R*^2 / E*).
fn jkr_unit(c: PairC, r_star: f32) -> f32 {
    let a0 = pow(c.c.y * r_star * r_star, 1.0 / 3.0);
    return a0 * a0 / r_star;
}

// JKR's attraction at a positive overlap (the CPU engine's `CohesionLaw::attraction`): Hertz's
// force less JKR's, 2 pi gamma R* (4/3 (D^1.5 - s^6) + 2 s^3).
fn jkr_attraction(c: PairC, r_star: f32, overlap: f32) -> f32 {
    let d = overlap / jkr_unit(c, r_star);
    let s = jkr_root(d);
    let s3 = s * s * s;
    return 2.0 * PI * c.c.x * r_star * (4.0 / 3.0 * (d * sqrt(d) - s3 * s3) + 2.0 * s3);
}

// The separation of a JKR contact, D = -0.4725 (x^1.5 = 1/4).
const JKR_SEPARATION: f32 = -0.4724704;

struct PairOut {
    touching: bool,
    // a JKR contact is on (touching, or necking past zero overlap): kept in the spring's w
    in_contact: bool,
    // force on a (b gets minus it)
    force: vec3<f32>,
    torque_a: vec3<f32>,
    torque_b: vec3<f32>,
    moment_a: f32,
    moment_b: f32,
    spring: vec3<f32>,
    rolling: vec3<f32>,
}

// The contact of a and b (a < b), from a's side: both particles call it with the same
// arguments, so both get the same bits.
fn pair_contact(a: u32, b: u32, spring_in: vec4<f32>, rolling_in: vec3<f32>) -> PairOut {
    var o: PairOut;
    o.touching = false;
    o.force = vec3<f32>(0.0);
    o.torque_a = vec3<f32>(0.0);
    o.torque_b = vec3<f32>(0.0);
    o.moment_a = 0.0;
    o.moment_b = 0.0;
    o.spring = vec3<f32>(0.0);
    o.rolling = vec3<f32>(0.0);
    o.in_contact = false;
    let d = rel(a, b);
    let ra = off[a].w;
    let rb = off[b].w;
    let rsum = ra + rb;
    let dist2 = dot(d, d);
    if (dist2 >= rsum * rsum) {
        // A JKR contact outlives zero overlap (necking) until its separation: only JKR's
        // attraction acts there, no Hertz load, so no friction (the CPU engine's kernel).
        // Most listed pairs are apart and were apart: only one that touched reads its constants.
        if (!JKR || spring_in.w == 0.0) {
            return o;
        }
        let c = pair_constants(cell[a].w, cell[b].w);
        if (c.c.x > 0.0) {
            let dist = sqrt(dist2);
            let r_star = ra * rb / rsum;
            let dd = (rsum - dist) / jkr_unit(c, r_star);
            if (dd >= JKR_SEPARATION) {
                let s3 = pow(jkr_root(dd), 3.0);
                let pull = 2.0 * PI * c.c.x * r_star * (4.0 / 3.0 * s3 * s3 - 2.0 * s3);
                o.touching = true;
                o.in_contact = true;
                o.force = d * (pull / dist);
            }
        }
        return o;
    }
    o.touching = true;
    o.in_contact = true;
    let dist = sqrt(dist2);
    let n = d * (1.0 / dist);
    let overlap = rsum - dist;
    let lever_a = ra - 0.5 * overlap;
    let lever_b = rb - 0.5 * overlap;
    let va = vel[a];
    let vb = vel[b];
    let wa = omg[a].xyz;
    let wb = omg[b].xyz;
    let vrel = va.xyz - vb.xyz - cross(wa * lever_a + wb * lever_b, n);
    let r_star = ra * rb / rsum;
    let m_star = va.w * vb.w / (va.w + vb.w);
    let c = pair_constants(cell[a].w, cell[b].w);
    let h = hertz_mindlin(c, r_star, m_star, overlap, n, vrel, spring_in.xyz);
    var force = h.force;
    if (LINEAR_COHESION && c.b.z > 0.0) {
        // Linear cohesion, k times the area of the circle where the undeformed spheres cut;
        // friction and rolling keep the Hertz load (the CPU engine's `CohesionLaw`).
        let a2 = overlap * (2.0 * ra - overlap) * (2.0 * rb - overlap)
            * (2.0 * rsum - overlap) / (4.0 * dist2);
        force -= n * (c.b.z * PI * a2);
    } else if (JKR && c.c.x > 0.0) {
        force -= n * jkr_attraction(c, r_star, overlap);
    }
    let n_cross_f = cross(n, force);
    o.force = force;
    o.torque_a = -n_cross_f * lever_a;
    o.torque_b = -n_cross_f * lever_b;
    o.spring = h.spring;
    if (epsd()) {
        let inertia_a = 1.0 / omg[a].w + va.w * ra * ra;
        let inertia_b = 1.0 / omg[b].w + vb.w * rb * rb;
        let r = epsd_rolling(n, wa - wb, h.stiffness, c.b.y, r_star, h.normal_force,
            inertia_a * inertia_b / (inertia_a + inertia_b), rolling_in);
        o.torque_a += r.torque;
        o.torque_b -= r.torque;
        o.rolling = r.spring;
    } else {
        let m = c.b.y * h.normal_force;
        o.moment_a = m * lever_a;
        o.moment_b = m * lever_b;
    }
    return o;
}
