//! Result formats: the final particle table, geometry force series, and ParaView snapshots
//! (legacy VTK). Functions write into any [`std::io::Write`]; opening files is the caller's job.

use std::io::{self, Write};

use crate::math::Vec3;
use crate::mesh::TriMesh;
use crate::particles::Particles;
use crate::world::GeometrySample;

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
            particles.id[k], p.x, p.y, p.z, v.x, v.y, v.z, w.x, w.y, w.z, particles.radius[k]
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
                s.time, s.force.x, s.force.y, s.force.z, s.torque.x, s.torque.y, s.torque.z
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
        writeln!(out, "{} {} {}", p.x, p.y, p.z)?;
    }
    writeln!(out, "VERTICES {n} {}", 2 * n)?;
    for k in 0..n {
        writeln!(out, "1 {k}")?;
    }
    writeln!(out, "POINT_DATA {n}")?;
    writeln!(out, "SCALARS radius double 1")?;
    writeln!(out, "LOOKUP_TABLE default")?;
    for r in &particles.radius {
        writeln!(out, "{r}")?;
    }
    writeln!(out, "SCALARS id double 1")?;
    writeln!(out, "LOOKUP_TABLE default")?;
    for id in &particles.id {
        writeln!(out, "{id}")?;
    }
    writeln!(out, "VECTORS velocity double")?;
    for v in &particles.velocity {
        writeln!(out, "{} {} {}", v.x, v.y, v.z)?;
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
        writeln!(out, "{} {} {}", p.x, p.y, p.z)?;
    }
    writeln!(out, "POLYGONS {} {}", triangles.len(), 4 * triangles.len())?;
    for t in triangles {
        writeln!(out, "3 {} {} {}", t[0], t[1], t[2])?;
    }
    Ok(())
}
