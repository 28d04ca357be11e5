//! The CPU engine, the reference: [`World::step`] as it is, one step per
//! [`Backend::advance`] (its sources are served inside the step), so a run loop driving it
//! sees every step, exactly as one that steps the world itself.

use repose_engine::kinematics::Motion;
use repose_engine::world::{Geometry, GeometryId, GeometrySample, World};

use super::{first_factory, Backend, BackendError, FactoryBooks, Grains, PlaneStress, Window};

/// The CPU engine's [`World`] as a [`Backend`].
#[derive(Debug)]
pub struct CpuBackend {
    world: World,
}

impl CpuBackend {
    pub fn new(world: World) -> CpuBackend {
        CpuBackend { world }
    }

    pub fn world(&self) -> &World {
        &self.world
    }
}

impl Backend for CpuBackend {
    fn engine_version(&self) -> String {
        repose_engine::VERSION.to_owned()
    }

    fn time(&self) -> f64 {
        self.world.time()
    }

    fn steps(&self) -> u64 {
        self.world.steps()
    }

    fn time_step(&self) -> f64 {
        self.world.config().time_step
    }

    fn advance(&mut self, _max_steps: u64) -> Result<u64, BackendError> {
        self.world.step();
        Ok(1)
    }

    fn grains(&mut self) -> Result<Grains<'_>, BackendError> {
        Ok(Grains::of(&self.world))
    }

    fn grain_count(&mut self) -> Result<usize, BackendError> {
        Ok(self.world.particles().len())
    }

    fn removed_count(&mut self) -> Result<u64, BackendError> {
        Ok(self.world.removed_count())
    }

    fn factory(&self) -> Option<FactoryBooks> {
        first_factory(self.world.sources())
    }

    fn geometries(&self) -> &[Geometry] {
        self.world.geometries()
    }

    fn geometry_series(&mut self, id: GeometryId) -> Result<Vec<GeometrySample>, BackendError> {
        Ok(self.world.geometry_series(id).to_vec())
    }

    fn clear_geometry_series(&mut self) {
        self.world.clear_geometry_series();
    }

    fn set_geometry_motion(&mut self, id: GeometryId, motion: Motion) -> Result<(), BackendError> {
        self.world.set_geometry_motion(id, motion);
        Ok(())
    }

    fn advance_sampling(
        &mut self,
        steps: u64,
        window: &Window,
    ) -> Result<PlaneStress, BackendError> {
        self.world.run(steps.max(1));
        Ok(window.stress_in(&self.world))
    }

    fn checkpoint_world(&self) -> Option<&World> {
        Some(&self.world)
    }

    fn into_world(self: Box<Self>) -> Result<World, BackendError> {
        Ok(self.world)
    }
}
