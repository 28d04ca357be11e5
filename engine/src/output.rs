//! Result formats: the final particle table, geometry force series, and ParaView snapshots
//! (legacy VTK). Functions write into any [`std::io::Write`]; opening files is the caller's job.

use std::io::{self, Write};

use crate::math::Vec3;
use crate::mesh::TriMesh;
use crate::particles::Particles;
use crate::world::GeometrySample;

/// A number as the writers print it: Rust's shortest round-trip form, in exponent notation
/// when it is tiny or huge. (`{}` alone never uses an exponent, so a grain at rest with a
/// velocity of 4e-310 m/s took 330 characters per field.)
struct Num(f64);

impl std::fmt::Display for Num {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let a = self.0.abs();
        if a == 0.0 || (1e-5..1e16).contains(&a) || !a.is_finite() {
            write!(f, "{}", self.0)
        } else {
            write!(f, "{:e}", self.0)
        }
    }
}

/// `id,x,y,z,vx,vy,vz,wx,wy,wz,radius`, one row per particle, in SI units.
pub fn write_particles_csv(out: &mut impl Write, particles: &Particles) -> io::Result<()> {
    writeln!(out, "id,x,y,z,vx,vy,vz,wx,wy,wz,radius")?;
    for k in 0..particles.len() {
        let (p, v, w) = (
            particles.position[k],
            particles.velocity[k],
            particles.angular_velocity[k],
        );
        writeln!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{}",
            particles.id[k],
            Num(p.x),
            Num(p.y),
            Num(p.z),
            Num(v.x),
            Num(v.y),
            Num(v.z),
            Num(w.x),
            Num(w.y),
            Num(w.z),
            Num(particles.radius[k])
        )?;
    }
    Ok(())
}

/// `geometry,time,fx,fy,fz,tx,ty,tz`: the force the particles exert on each geometry and its
/// torque about the geometry's reference point (its rotation axis point).
pub fn write_geometry_csv<'a>(
    out: &mut impl Write,
    series: impl IntoIterator<Item = (&'a str, &'a [GeometrySample])>,
) -> io::Result<()> {
    writeln!(out, "geometry,time,fx,fy,fz,tx,ty,tz")?;
    for (name, samples) in series {
        for s in samples {
            writeln!(
                out,
                "{name},{},{},{},{},{},{},{}",
                Num(s.time),
                Num(s.force.x),
                Num(s.force.y),
                Num(s.force.z),
                Num(s.torque.x),
                Num(s.torque.y),
                Num(s.torque.z)
            )?;
        }
    }
    Ok(())
}

/// Particles as a legacy-VTK polydata file of points with `radius`, `id` and `velocity`
/// attributes (ParaView: Glyph filter, sphere, scale by `radius`).
pub fn write_particles_vtk(
    out: &mut impl Write,
    particles: &Particles,
    time: f64,
) -> io::Result<()> {
    let n = particles.len();
    writeln!(out, "# vtk DataFile Version 3.0")?;
    writeln!(out, "repose particles t={time}")?;
    writeln!(out, "ASCII")?;
    writeln!(out, "DATASET POLYDATA")?;
    writeln!(out, "POINTS {n} double")?;
    for p in &particles.position {
        writeln!(out, "{} {} {}", Num(p.x), Num(p.y), Num(p.z))?;
    }
    writeln!(out, "VERTICES {n} {}", 2 * n)?;
    for k in 0..n {
        writeln!(out, "1 {k}")?;
    }
    writeln!(out, "POINT_DATA {n}")?;
    writeln!(out, "SCALARS radius double 1")?;
    writeln!(out, "LOOKUP_TABLE default")?;
    for r in &particles.radius {
        writeln!(out, "{}", Num(*r))?;
    }
    writeln!(out, "SCALARS id double 1")?;
    writeln!(out, "LOOKUP_TABLE default")?;
    for id in &particles.id {
        writeln!(out, "{id}")?;
    }
    writeln!(out, "VECTORS velocity double")?;
    for v in &particles.velocity {
        writeln!(out, "{} {} {}", Num(v.x), Num(v.y), Num(v.z))?;
    }
    Ok(())
}

/// A mesh placed in the world (vertices mapped through `place`) as legacy-VTK polydata.
pub fn write_mesh_vtk(
    out: &mut impl Write,
    mesh: &TriMesh,
    place: impl Fn(Vec3) -> Vec3,
    name: &str,
) -> io::Result<()> {
    let vertices = mesh.vertices();
    let triangles = mesh.triangles();
    writeln!(out, "# vtk DataFile Version 3.0")?;
    writeln!(out, "repose geometry {name}")?;
    writeln!(out, "ASCII")?;
    writeln!(out, "DATASET POLYDATA")?;
    writeln!(out, "POINTS {} double", vertices.len())?;
    for v in vertices {
        let p = place(*v);
        writeln!(out, "{} {} {}", Num(p.x), Num(p.y), Num(p.z))?;
    }
    writeln!(out, "POLYGONS {} {}", triangles.len(), 4 * triangles.len())?;
    for t in triangles {
        writeln!(out, "3 {} {} {}", t[0], t[1], t[2])?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::Num;

    #[test]
    fn numbers_round_trip_and_tiny_ones_stay_short() {
        for x in [
            0.0, -0.0, 1.0, -2.5e-3, 1e-5, 9.99e-6, 4.4e-310, -3.2e-20, 1.5e16, 123456.789, 0.001,
        ] {
            let text = Num(x).to_string();
            assert_eq!(text.parse::<f64>().unwrap(), x, "{text}");
            assert!(text.len() <= 24, "{x}: {text}");
        }
        assert_eq!(Num(0.001).to_string(), "0.001");
        assert_eq!(Num(4.4e-310).to_string(), "4.4e-310");
    }
}
