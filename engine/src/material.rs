//! Materials, material-pair interaction coefficients and the precomputed pair table.
//!
//! The user-facing form ([`MaterialSet`]) is keyed by material *names* so that a JSON file can
//! be written by hand. [`MaterialSet::build`] validates it and produces a [`MaterialTable`]:
//! dense, index-addressed, with every Hertz-Mindlin equivalent quantity that depends only on the
//! two materials (E*, G*, β) computed once, so the contact loop does a single table lookup.

use serde::{Deserialize, Serialize};

use crate::contact::CohesionLaw;

/// Index of a material in a [`MaterialTable`] (the order of [`MaterialSet::materials`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub struct MaterialId(pub u16);

/// Bulk properties of one material (particle or geometry).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Material {
    /// Unique name, used to refer to the material from interactions and geometries.
    pub name: String,
    /// Solid density, kg/m³.
    pub density: f64,
    /// Young's modulus E, Pa.
    pub youngs_modulus: f64,
    /// Poisson's ratio ν, dimensionless, in (0, 0.5).
    pub poisson: f64,
}

impl Material {
    /// Shear modulus G = E / (2 (1 + ν)), Pa.
    pub fn shear_modulus(&self) -> f64 {
        self.youngs_modulus / (2.0 * (1.0 + self.poisson))
    }

    /// The paper's desert-sand particle material: 2664 kg/m³, E = 3.67 MPa, ν = 0.36.
    pub fn paper_soil() -> Material {
        Material {
            name: "soil".into(),
            density: 2664.0,
            youngs_modulus: 3.67e6,
            poisson: 0.36,
        }
    }

    /// The paper's steel (funnel, plate, auger): 7850 kg/m³, E = 210 GPa, ν = 0.30.
    pub fn paper_steel() -> Material {
        Material {
            name: "steel".into(),
            density: 7850.0,
            youngs_modulus: 2.1e11,
            poisson: 0.30,
        }
    }
}

/// Contact coefficients of one (unordered) pair of materials.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Interaction {
    /// Coefficient of restitution e, in (0, 1].
    pub restitution: f64,
    /// Coefficient of static (Coulomb) friction μs, >= 0.
    pub static_friction: f64,
    /// Coefficient of rolling friction μr, >= 0 (dimensionless, EDEM convention: the rolling
    /// torque is μr times the normal force times a lever arm).
    pub rolling_friction: f64,
    /// The cohesion law of the pair. Absent from a JSON document means none, so every
    /// document written before cohesion existed reads as before. It is always written out
    /// (`{"model": "none"}`), so a spec's `--set` and a batch's factor paths can reach it.
    #[serde(default)]
    pub cohesion: Cohesion,
}

impl Interaction {
    /// Restitution and friction without cohesion.
    pub fn new(restitution: f64, static_friction: f64, rolling_friction: f64) -> Interaction {
        Interaction {
            restitution,
            static_friction,
            rolling_friction,
            cohesion: Cohesion::None,
        }
    }
}

/// A cohesion law between two materials: an attractive normal force added to Hertz-Mindlin's.
///
/// JSON: `{"model": "none"}`, `{"model": "linear", "energy_density": 3.0e5}` or
/// `{"model": "jkr", "surface_energy": 0.1}`. See [`crate::contact::CohesionLaw`] for the
/// forces, and for which normal force friction and rolling resistance use.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "model", rename_all = "snake_case", deny_unknown_fields)]
pub enum Cohesion {
    /// No cohesion: the contact law is exactly Hertz-Mindlin.
    #[default]
    None,
    /// EDEM's linear cohesion, LIGGGHTS' `cohesion sjkr`: F = k A, with k the cohesion energy
    /// density (J/m³) and A the contact area (the circle where the two undeformed spheres, or
    /// the sphere and the wall plane, intersect).
    Linear {
        /// k, J/m³, >= 0.
        energy_density: f64,
    },
    /// Johnson-Kendall-Roberts: the elastic normal force of an adhesive Hertz contact, pull-off
    /// force 1.5 π γ R* (EDEM's convention: γ is the work of adhesion of the pair).
    Jkr {
        /// γ, J/m², >= 0.
        surface_energy: f64,
    },
}

impl Cohesion {
    pub fn is_none(&self) -> bool {
        matches!(self, Cohesion::None)
    }
}

/// An [`Interaction`] between two named materials. Order of `a` and `b` does not matter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InteractionEntry {
    pub a: String,
    pub b: String,
    #[serde(flatten)]
    pub coefficients: Interaction,
}

/// The serialisable description of all materials and all pair interactions of a simulation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaterialSet {
    pub materials: Vec<Material>,
    pub interactions: Vec<InteractionEntry>,
    /// How the damping ratio β is derived from the coefficient of restitution.
    #[serde(default)]
    pub damping_law: DampingLaw,
}

/// How the normal/tangential damping ratio β follows from the coefficient of restitution e.
///
/// EDEM's formula β = ln e / sqrt(ln² e + π²) makes the Hertz spring-dashpot rebound with
/// exactly e only if the normal force may become attractive at the end of the contact (the
/// dashpot pulls while the spring has almost relaxed). We forbid attraction (the total normal
/// force is clamped at 0), and then the contact ends early, when the force first reaches 0,
/// with a HIGHER rebound speed: e = 0.2 → 0.325, 0.5 → 0.550, 0.9 → 0.902. Because Hertz with
/// this δ^¼ dashpot is self-similar (Tsuji et al. 1992), the effective restitution depends on β
/// alone, so we can invert it once per material pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum DampingLaw {
    /// β chosen so that the clamped (non-attractive) contact rebounds with exactly the input e
    /// (found by bisection on the dimensionless impact; see [`restitution_damping_ratio`]).
    #[default]
    ExactRestitution,
    /// EDEM's closed-form β = ln e / sqrt(ln² e + π²) (rebound slightly above e, see above).
    EdemFormula,
}

/// Why a [`MaterialSet`] was rejected. Messages name the offending field by its path, e.g.
/// `materials.soil.poisson must be in (0, 0.5)`, so a user can find it in the input file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MaterialError {
    #[error("{field} must be {requirement} (got {value})")]
    OutOfRange {
        field: String,
        requirement: &'static str,
        value: f64,
    },
    #[error("materials: the name {0:?} is used more than once")]
    DuplicateMaterial(String),
    #[error("materials: at least one material is required")]
    NoMaterials,
    #[error("materials: at most 65535 materials are supported")]
    TooManyMaterials,
    #[error("{field} refers to unknown material {name:?}")]
    UnknownMaterial { field: String, name: String },
    #[error("interactions: the pair ({a}, {b}) is given more than once")]
    DuplicateInteraction { a: String, b: String },
    #[error("interactions: no interaction given for the pair ({a}, {b})")]
    MissingInteraction { a: String, b: String },
}

fn check(
    field: impl FnOnce() -> String,
    value: f64,
    ok: bool,
    requirement: &'static str,
) -> Result<(), MaterialError> {
    if ok && value.is_finite() {
        Ok(())
    } else {
        Err(MaterialError::OutOfRange {
            field: field(),
            requirement,
            value,
        })
    }
}

impl Material {
    fn validate(&self) -> Result<(), MaterialError> {
        let n = &self.name;
        check(
            || format!("materials.{n}.density"),
            self.density,
            self.density > 0.0,
            "> 0",
        )?;
        check(
            || format!("materials.{n}.youngs_modulus"),
            self.youngs_modulus,
            self.youngs_modulus > 0.0,
            "> 0",
        )?;
        check(
            || format!("materials.{n}.poisson"),
            self.poisson,
            self.poisson > 0.0 && self.poisson < 0.5,
            "in (0, 0.5)",
        )
    }
}

impl Interaction {
    fn validate(&self, a: &str, b: &str) -> Result<(), MaterialError> {
        let path = |f: &str| format!("interactions.{a}-{b}.{f}");
        check(
            || path("restitution"),
            self.restitution,
            self.restitution > 0.0 && self.restitution <= 1.0,
            "in (0, 1]",
        )?;
        check(
            || path("static_friction"),
            self.static_friction,
            self.static_friction >= 0.0,
            ">= 0",
        )?;
        check(
            || path("rolling_friction"),
            self.rolling_friction,
            self.rolling_friction >= 0.0,
            ">= 0",
        )?;
        match self.cohesion {
            Cohesion::None => Ok(()),
            Cohesion::Linear { energy_density } => check(
                || path("cohesion.energy_density"),
                energy_density,
                energy_density >= 0.0,
                ">= 0",
            ),
            Cohesion::Jkr { surface_energy } => check(
                || path("cohesion.surface_energy"),
                surface_energy,
                surface_energy >= 0.0,
                ">= 0",
            ),
        }
    }
}

impl MaterialSet {
    /// The paper's two materials (soil, steel) with soil-soil and soil-steel coefficients and
    /// a steel-steel entry (never used by a steel-only geometry pair, but required for
    /// completeness of the table).
    pub fn paper(soil_soil: Interaction, soil_steel: Interaction) -> MaterialSet {
        MaterialSet {
            damping_law: DampingLaw::default(),
            materials: vec![Material::paper_soil(), Material::paper_steel()],
            interactions: vec![
                InteractionEntry {
                    a: "soil".into(),
                    b: "soil".into(),
                    coefficients: soil_soil,
                },
                InteractionEntry {
                    a: "soil".into(),
                    b: "steel".into(),
                    coefficients: soil_steel,
                },
                InteractionEntry {
                    a: "steel".into(),
                    b: "steel".into(),
                    coefficients: Interaction::new(0.5, 0.3, 0.01),
                },
            ],
        }
    }

    /// Validate and precompute the dense pair table.
    pub fn build(&self) -> Result<MaterialTable, MaterialError> {
        if self.materials.is_empty() {
            return Err(MaterialError::NoMaterials);
        }
        if self.materials.len() > u16::MAX as usize {
            return Err(MaterialError::TooManyMaterials);
        }
        for (k, m) in self.materials.iter().enumerate() {
            if self.materials[..k].iter().any(|o| o.name == m.name) {
                return Err(MaterialError::DuplicateMaterial(m.name.clone()));
            }
            m.validate()?;
        }
        let n = self.materials.len();
        let index_of = |name: &str, field: String| {
            self.materials.iter().position(|m| m.name == name).ok_or(
                MaterialError::UnknownMaterial {
                    field,
                    name: name.to_string(),
                },
            )
        };
        let mut given: Vec<Option<Interaction>> = vec![None; n * n];
        for (k, entry) in self.interactions.iter().enumerate() {
            let a = index_of(&entry.a, format!("interactions[{k}].a"))?;
            let b = index_of(&entry.b, format!("interactions[{k}].b"))?;
            entry.coefficients.validate(&entry.a, &entry.b)?;
            if given[a * n + b].is_some() {
                return Err(MaterialError::DuplicateInteraction {
                    a: entry.a.clone(),
                    b: entry.b.clone(),
                });
            }
            given[a * n + b] = Some(entry.coefficients);
            given[b * n + a] = Some(entry.coefficients);
        }
        let mut pairs: Vec<PairConstants> = Vec::with_capacity(n * n);
        for a in 0..n {
            for b in 0..n {
                let coefficients =
                    given[a * n + b].ok_or_else(|| MaterialError::MissingInteraction {
                        a: self.materials[a].name.clone(),
                        b: self.materials[b].name.clone(),
                    })?;
                let mut constants =
                    PairConstants::new(&self.materials[a], &self.materials[b], &coefficients);
                if self.damping_law == DampingLaw::ExactRestitution {
                    // The table is symmetric: reuse the (b, a) entry already solved.
                    constants.beta = if b < a {
                        pairs[b * n + a].beta
                    } else {
                        restitution_damping_ratio(coefficients.restitution)
                    };
                }
                pairs.push(constants);
            }
        }
        let any_jkr = pairs
            .iter()
            .any(|p| matches!(p.cohesion, CohesionLaw::Jkr { .. }));
        let any_cohesion = pairs.iter().any(|p| p.cohesion.is_on());
        Ok(MaterialTable {
            materials: self.materials.clone(),
            pairs,
            any_jkr,
            any_cohesion,
        })
    }
}

/// Everything the contact law needs that depends only on the two materials.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PairConstants {
    /// Equivalent Young's modulus E*: 1/E* = (1-νi²)/Ei + (1-νj²)/Ej.
    pub e_star: f64,
    /// Equivalent shear modulus G*: 1/G* = (2-νi)/Gi + (2-νj)/Gj.
    pub g_star: f64,
    /// Damping ratio β = ln e / sqrt(ln² e + π²) (<= 0; zero for e = 1).
    pub beta: f64,
    pub static_friction: f64,
    pub rolling_friction: f64,
    pub restitution: f64,
    /// sqrt(St / Sn) = sqrt(4 G* / E*): tangential over normal dashpot coefficient.
    pub tangential_to_normal_damping: f64,
    /// The pair's cohesion, in the form the contact loop uses (tested once per contact).
    pub cohesion: CohesionLaw,
}

impl PairConstants {
    pub fn new(a: &Material, b: &Material, coefficients: &Interaction) -> PairConstants {
        let e_star = 1.0
            / ((1.0 - a.poisson * a.poisson) / a.youngs_modulus
                + (1.0 - b.poisson * b.poisson) / b.youngs_modulus);
        let g_star =
            1.0 / ((2.0 - a.poisson) / a.shear_modulus() + (2.0 - b.poisson) / b.shear_modulus());
        PairConstants {
            e_star,
            g_star,
            beta: damping_ratio(coefficients.restitution),
            static_friction: coefficients.static_friction,
            rolling_friction: coefficients.rolling_friction,
            restitution: coefficients.restitution,
            tangential_to_normal_damping: (4.0 * g_star / e_star).sqrt(),
            cohesion: CohesionLaw::new(&coefficients.cohesion, e_star),
        }
    }
}

/// EDEM's damping ratio β = ln e / sqrt(ln² e + π²) for a coefficient of restitution e.
pub fn damping_ratio(restitution: f64) -> f64 {
    let ln_e = restitution.ln();
    ln_e / (ln_e * ln_e + std::f64::consts::PI * std::f64::consts::PI).sqrt()
}

/// Rebound speed / impact speed of a head-on Hertz impact with the damping ratio `beta`
/// when the normal force may not become attractive (the contact ends when it reaches 0).
///
/// Dimensionless (m* = R* = E* = impact speed = 1; the result depends on β only), integrated
/// with classical Runge-Kutta at 1/2870 of the contact time.
pub fn clamped_restitution(beta: f64) -> f64 {
    let damping = -2.0 * (5.0f64 / 6.0).sqrt() * beta;
    // Force pushing the bodies apart; `closing` > 0 while they approach.
    let force = |overlap: f64, closing: f64| {
        let d = overlap.max(0.0);
        4.0 / 3.0 * d * d.sqrt() + damping * (2.0 * d.sqrt()).sqrt() * closing
    };
    let derivative = |d: f64, v: f64| (v, -force(d, v).max(0.0));
    let h = 1.0e-3;
    let (mut d, mut v) = (0.0f64, 1.0f64);
    for _ in 0..1_000_000 {
        let k1 = derivative(d, v);
        let k2 = derivative(d + 0.5 * h * k1.0, v + 0.5 * h * k1.1);
        let k3 = derivative(d + 0.5 * h * k2.0, v + 0.5 * h * k2.1);
        let k4 = derivative(d + h * k3.0, v + h * k3.1);
        d += h / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0);
        v += h / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1);
        if v < 0.0 && (d <= 0.0 || force(d, v) <= 0.0) {
            return -v;
        }
    }
    0.0
}

/// The damping ratio β (<= 0) for which [`clamped_restitution`] equals `restitution`.
pub fn restitution_damping_ratio(restitution: f64) -> f64 {
    if restitution >= 1.0 {
        return 0.0;
    }
    // clamped_restitution decreases monotonically with -β.
    let (mut lo, mut hi) = (-50.0f64, 0.0f64);
    for _ in 0..50 {
        let mid = 0.5 * (lo + hi);
        if clamped_restitution(mid) > restitution {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Validated, index-addressed materials and the dense n×n pair table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MaterialTable {
    materials: Vec<Material>,
    pairs: Vec<PairConstants>,
    /// Some pair has JKR cohesion, whose contacts outlive zero overlap (necking).
    any_jkr: bool,
    /// Some pair has cohesion (linear or JKR).
    any_cohesion: bool,
}

impl MaterialTable {
    pub fn len(&self) -> usize {
        self.materials.len()
    }

    pub fn is_empty(&self) -> bool {
        self.materials.is_empty()
    }

    pub fn material(&self, id: MaterialId) -> &Material {
        &self.materials[id.0 as usize]
    }

    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// The id of the material called `name`.
    pub fn id(&self, name: &str) -> Option<MaterialId> {
        self.materials
            .iter()
            .position(|m| m.name == name)
            .map(|k| MaterialId(k as u16))
    }

    /// Whether some pair has JKR cohesion (contacts that may continue at negative overlap).
    #[inline]
    pub fn any_jkr(&self) -> bool {
        self.any_jkr
    }

    /// Whether some pair has cohesion (linear or JKR).
    pub fn any_cohesion(&self) -> bool {
        self.any_cohesion
    }

    /// Precomputed constants of the pair (a, b); symmetric.
    #[inline]
    pub fn pair(&self, a: MaterialId, b: MaterialId) -> &PairConstants {
        &self.pairs[a.0 as usize * self.materials.len() + b.0 as usize]
    }
}

/// The paper's (and a common EDEM) choice of time step: 20 % of the Rayleigh time.
pub const DEFAULT_RAYLEIGH_FRACTION: f64 = 0.2;

/// Rayleigh time T_R = π R sqrt(ρ/G) / (0.1631 ν + 0.8766) of a particle of radius R (s): the
/// time a Rayleigh surface wave needs to cross it. EDEM recommends a time step of 20-40 % of T_R
/// of the smallest particle; the paper uses 20 %.
pub fn rayleigh_time(radius: f64, material: &Material) -> f64 {
    std::f64::consts::PI * radius * (material.density / material.shear_modulus()).sqrt()
        / (0.1631 * material.poisson + 0.8766)
}

/// Duration of a Hertzian (elastic) impact at normal approach speed `speed`:
/// t_c = 2.87 (m*² / (R* E*² v))^(1/5). Faster impacts are shorter, so a time step must resolve
/// the fastest expected one.
pub fn hertz_contact_time(m_star: f64, r_star: f64, e_star: f64, speed: f64) -> f64 {
    2.87 * (m_star * m_star / (r_star * e_star * e_star * speed)).powf(0.2)
}

/// A time step that is too coarse for the fastest expected impact. Returned (never printed)
/// so the caller can log it.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeStepWarning {
    pub time_step: f64,
    /// Hertz contact time of a head-on impact of two of the smallest particles at the expected
    /// maximum impact speed.
    pub contact_time: f64,
    pub impact_speed: f64,
    /// Number of steps that resolve that contact (we warn below [`MIN_STEPS_PER_CONTACT`]).
    pub steps_per_contact: f64,
}

/// Fewer steps than this per Hertz contact makes the collision response inaccurate.
pub const MIN_STEPS_PER_CONTACT: f64 = 10.0;

impl std::fmt::Display for TimeStepWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "time step {:.3e} s resolves an impact at {} m/s (Hertz contact time {:.3e} s) with only \
             {:.1} steps; use at most {:.3e} s",
            self.time_step,
            self.impact_speed,
            self.contact_time,
            self.steps_per_contact,
            self.contact_time / MIN_STEPS_PER_CONTACT
        )
    }
}

/// Check `time_step` against the Hertz contact time of two particles of `radius` and
/// `material` colliding head-on at `max_impact_speed`.
pub fn check_time_step(
    time_step: f64,
    radius: f64,
    material: &Material,
    max_impact_speed: f64,
) -> Option<TimeStepWarning> {
    let mass = material.density * 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3);
    let e_star = material.youngs_modulus / (2.0 * (1.0 - material.poisson * material.poisson));
    let contact_time = hertz_contact_time(mass / 2.0, radius / 2.0, e_star, max_impact_speed);
    let steps_per_contact = contact_time / time_step;
    (steps_per_contact < MIN_STEPS_PER_CONTACT).then_some(TimeStepWarning {
        time_step,
        contact_time,
        impact_speed: max_impact_speed,
        steps_per_contact,
    })
}
