//! The world's device buffers: one per binding of the shader's main group, in binding order,
//! and the moving geometries' frames; their sizes, the control words' layout and the
//! adapter's limits they must fit.

use wgpu::util::DeviceExt;

use crate::movers::Frames;
use crate::scene::{Scene, BIN_CAPACITY, NEIGHBOUR_CAPACITY, WALL_CAPACITY};

/// Steps encoded into one command buffer: the frames buffer holds a block for the force
/// evaluation of each and of a Verlet start-up.
pub(super) const STEPS_PER_SUBMIT: u64 = 25;

/// Load records (one per recorded force evaluation, each a force and a torque per moving
/// geometry) the device holds before the host reads them back.
pub(super) const SERIES_RECORDS: usize = 16_384;

/// One force evaluation's block of moving-geometry frames (a multiple of every adapter's
/// uniform offset alignment, at most 256).
pub(super) const FRAME_BYTES: u64 = std::mem::size_of::<Frames>() as u64;
const _: () = assert!(FRAME_BYTES % 256 == 0);

/// Control words (the shader's `ctl`).
pub(super) mod ctl {
    pub const REBUILD: usize = 0;
    pub const REBUILDS: usize = 1;
    pub const NEIGHBOUR_OVERFLOW: usize = 2;
    pub const BIN_OVERFLOW: usize = 3;
    pub const REMOVED: usize = 4;
    pub const FASTEST: usize = 5;
    pub const WALL_OVERFLOW: usize = 6;
    pub const WORDS: usize = 8;
}

/// Bindings of the main group (the shader's `@group(0)`).
pub(super) const MAIN_BINDINGS: usize = 23;

/// The buffers, named as the shader names its bindings.
pub(super) struct Buffers {
    pub cell: wgpu::Buffer,
    pub off: wgpu::Buffer,
    pub vel: wgpu::Buffer,
    pub omg: wgpu::Buffer,
    pub frc: wgpu::Buffer,
    pub trq: wgpu::Buffer,
    pub disp: wgpu::Buffer,
    pub nbr: wgpu::Buffer,
    pub nbn: wgpu::Buffer,
    pub spr: wgpu::Buffer,
    pub nbr2: wgpu::Buffer,
    /// The cell each slot was binned in at the last rebuild (`commit` empties those).
    pub binned: wgpu::Buffer,
    pub spr2: wgpu::Buffer,
    pub bins: wgpu::Buffer,
    pub binn: wgpu::Buffer,
    pub walls: wgpu::Buffer,
    pub tris: wgpu::Buffer,
    pub pc: wgpu::Buffer,
    pub ctl: wgpu::Buffer,
    pub tri_grid: wgpu::Buffer,
    /// Each grain's load on each moving geometry, then their sums (`reduce_loads`).
    pub wload: wgpu::Buffer,
    pub series: wgpu::Buffer,
    /// Each grain's share of a sampled slab's stress sums (`run_sampling_slab`).
    pub slab: wgpu::Buffer,
    /// One block of frames per force evaluation of a submission (its steps and a Verlet
    /// start-up), bound at a dynamic offset.
    pub frames: wgpu::Buffer,
    /// Bytes of device memory they take.
    pub bytes: u64,
}

/// EPSD keeps a rolling spring after each tangential one (the shader's `epsd()`).
fn springs(scene: &Scene) -> u64 {
    if scene.params.epsd() {
        2
    } else {
        1
    }
}

/// Staging bytes per grain slot of the largest read-back (the grains' voxel, offset,
/// velocity and spin records), admitted with a world's buffers.
pub(super) const READ_BACK_BYTES_PER_SLOT: u64 = 4 * 16;

/// Bytes of device memory `scene`'s buffers take ([`Buffers::bytes`]), known before any is
/// allocated: what a world is admitted with (besides its read-back staging).
pub(super) fn footprint(scene: &Scene) -> u64 {
    let size = |slice: usize| slice as u64;
    let n = scene.cell.len() as u64;
    let springs = springs(scene);
    let list = n * NEIGHBOUR_CAPACITY as u64;
    let cells = scene.grid.cells() as u64;
    let movers = scene.movers.len() as u64;
    let tris = if scene.tris.is_empty() {
        80
    } else {
        size(std::mem::size_of_val(&scene.tris[..]))
    };
    let uploaded = size(std::mem::size_of_val(&scene.cell[..]))
        + size(std::mem::size_of_val(&scene.off[..]))
        + size(std::mem::size_of_val(&scene.vel[..]))
        + size(std::mem::size_of_val(&scene.omg[..]))
        + tris
        + size(std::mem::size_of_val(&scene.tri_grid[..]))
        + size(std::mem::size_of_val(&scene.pairs[..]));
    let zeroed = 3 * n * 16 // frc, trq, disp
        + list * 4 // nbr
        + n * 4 // nbn
        + 2 * list * 16 * springs // spr, spr2
        + list * 4 // nbr2
        + n * 4 // binned
        + cells * BIN_CAPACITY as u64 * 4 // bins
        + cells * 4 // binn
        + n * WALL_CAPACITY as u64 * 16 * (1 + springs) // walls
        + ctl::WORDS as u64 * 4
        + n * movers * 32 // wload
        + SERIES_RECORDS as u64 * movers * 32 // series
        + n * 16; // slab
    uploaded + zeroed + FRAME_BYTES * (STEPS_PER_SUBMIT + 1)
}

/// The largest binding `scene` needs, bytes.
pub(super) fn largest_binding(scene: &Scene) -> u64 {
    let n = scene.cell.len();
    (n * NEIGHBOUR_CAPACITY * 16 * springs(scene) as usize)
        .max(scene.grid.cells() * BIN_CAPACITY * 4)
        .max(scene.tri_grid.len() * 4) as u64
}

impl Buffers {
    /// `scene`'s buffers on `device`: the particles, triangles, lists and pair table
    /// uploaded, the rest zeroed.
    pub fn new(device: &wgpu::Device, scene: &Scene) -> Buffers {
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_SRC
            | wgpu::BufferUsages::COPY_DST;
        let mut bytes = 0u64;
        let mut init = |label: &str, contents: &[u8]| {
            bytes += contents.len() as u64;
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some(label),
                contents,
                usage: storage,
            })
        };
        let cell = init("cell", bytemuck::cast_slice(&scene.cell));
        let off = init("off", bytemuck::cast_slice(&scene.off));
        let vel = init("vel", bytemuck::cast_slice(&scene.vel));
        let omg = init("omg", bytemuck::cast_slice(&scene.omg));
        let tris_data: Vec<u8> = if scene.tris.is_empty() {
            vec![0u8; 80]
        } else {
            bytemuck::cast_slice(&scene.tris).to_vec()
        };
        let tris = init("tris", &tris_data);
        let tri_grid = init("tri grid", bytemuck::cast_slice(&scene.tri_grid));
        let pc = init("pairs", bytemuck::cast_slice(&scene.pairs));
        let mut zeroed = |label: &str, size: u64| {
            bytes += size;
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size: size.max(16),
                usage: storage,
                mapped_at_creation: false,
            })
        };
        let n64 = scene.cell.len() as u64;
        let springs = springs(scene);
        let list = n64 * NEIGHBOUR_CAPACITY as u64;
        let cells = scene.grid.cells() as u64;
        let movers = scene.movers.len() as u64;
        let mut buffers = Buffers {
            frc: zeroed("frc", n64 * 16),
            trq: zeroed("trq", n64 * 16),
            disp: zeroed("disp", n64 * 16),
            nbr: zeroed("nbr", list * 4),
            nbn: zeroed("nbn", n64 * 4),
            spr: zeroed("spr", list * 16 * springs),
            nbr2: zeroed("nbr2", list * 4),
            binned: zeroed("binned", n64 * 4),
            spr2: zeroed("spr2", list * 16 * springs),
            bins: zeroed("bins", cells * BIN_CAPACITY as u64 * 4),
            binn: zeroed("binn", cells * 4),
            walls: zeroed("walls", n64 * WALL_CAPACITY as u64 * 16 * (1 + springs)),
            ctl: zeroed("ctl", ctl::WORDS as u64 * 4),
            wload: zeroed("wload", n64 * movers * 32),
            series: zeroed("series", SERIES_RECORDS as u64 * movers * 32),
            slab: zeroed("slab", n64 * 16),
            frames: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("frames"),
                size: FRAME_BYTES * (STEPS_PER_SUBMIT + 1),
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            cell,
            off,
            vel,
            omg,
            tris,
            pc,
            tri_grid,
            bytes,
        };
        buffers.bytes += buffers.frames.size();
        buffers
    }

    /// The main group's buffers in binding order (the shader's `@binding(k)`).
    pub fn main_group(&self) -> [&wgpu::Buffer; MAIN_BINDINGS] {
        [
            &self.cell,
            &self.off,
            &self.vel,
            &self.omg,
            &self.frc,
            &self.trq,
            &self.disp,
            &self.nbr,
            &self.nbn,
            &self.spr,
            &self.nbr2,
            &self.binned,
            &self.spr2,
            &self.bins,
            &self.binn,
            &self.walls,
            &self.tris,
            &self.pc,
            &self.ctl,
            &self.tri_grid,
            &self.wload,
            &self.series,
            &self.slab,
        ]
    }
}
