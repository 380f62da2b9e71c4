//! Cameras and the film: one record per sensor, and the pixel filter's sampling table in
//! the material data.

use super::{Feature, Upload};
use crate::gpu::{self, Buffer, SpecValue};
use crate::render::{filter, texel_buffer};
use crate::shared::SensorRecord;

pub struct Sensors {
    buffer: Buffer,
    /// 1 + the offset of the pixel filter's table in the material data, or 0 for the box
    /// filter (`Globals::filter_table`).
    pub filter_table: u32,
}

impl Sensors {
    pub fn build(up: &mut Upload) -> gpu::Result<Sensors> {
        let scene = up.scene;
        let aspect = scene.film.width as f32 / scene.film.height as f32;
        let records: Vec<SensorRecord> = scene
            .sensors
            .iter()
            .map(|s| SensorRecord {
                origin: s.origin.into(),
                right: s.right.into(),
                up: s.up.into(),
                forward: s.forward.into(),
                tan_half_fov_y: (s.fov_y.to_radians() * 0.5).tan(),
                aspect,
                ortho_half_height: s.ortho_height.map_or(0.0, |h| 0.5 * h),
                lens_radius: s.lens.map_or(0.0, |l| l.aperture_radius),
                focus_distance: s.lens.map_or(0.0, |l| l.focus_distance),
                pad: [0; 3],
            })
            .collect();
        let filter_table = match filter::table(scene.pixel_filter) {
            None => 0,
            Some(table) => 1 + up.data.constant(&table).offset as u32,
        };
        Ok(Sensors { buffer: texel_buffer(up.ctx, "sensors", &records)?, filter_table })
    }
}

impl Feature for Sensors {
    fn bindings(&self) -> Vec<(&'static str, &Buffer)> {
        vec![("Sensors", &self.buffer)]
    }

    fn spec(&self) -> Vec<(&'static str, SpecValue)> {
        Vec::new()
    }
}
