//! Warnings about what a scene asks for and will not get when it is rendered, one line
//! each ([`Scene::render_warnings`]).

use super::model::{ParamTarget, Scene, TextureValue as _};
use glam::Vec3;

impl Scene {
    /// What the scene asks for and will not get when it is rendered (no light, a texture
    /// without texture coordinates to look it up, ...), one line each. Unlike
    /// [`Self::warnings`] (what loading approximated), these hold for a scene built in code
    /// too.
    pub fn render_warnings(&self) -> Vec<String> {
        lighting_warnings(self)
    }

    /// Whether anything lights the scene: an emitting mesh with a triangle of non-zero
    /// area, a light, or an environment (emitting or optimised ones count).
    pub fn has_light(&self) -> bool {
        let optimised = |target: ParamTarget| self.optimise.params.iter().any(|p| p.target == target);
        let meshes =
            self.meshes.iter().enumerate().any(|(i, mesh)| (optimised(ParamTarget::Emission { mesh: i }) || mesh.emission.any_positive()) && has_area(mesh));
        let environment = optimised(ParamTarget::Environment) || (self.environment.value.any_positive() && self.environment.scale > 0.0);
        meshes || environment || !self.lights.is_empty()
    }
}

fn has_area(mesh: &super::model::Mesh) -> bool {
    mesh.indices.iter().any(|idx| {
        let [a, b, c] = idx.map(|k| Vec3::from(mesh.positions[k as usize]));
        (b - a).cross(c - a).length() > 0.0
    })
}

/// What the scene will not get: light (no emitting triangle of non-zero area, no delta
/// light and no environment: it renders black), light from an emitting mesh whose triangles
/// all have zero area (an emitter table cannot sample them), or a normal map or an alpha
/// texture on a mesh without texture coordinates (neither is applied: the map has no
/// tangents, the alpha nowhere to be looked up).
fn lighting_warnings(scene: &Scene) -> Vec<String> {
    let mut out = Vec::new();
    let path = scene.path.display();
    let optimised = |target: ParamTarget| scene.optimise.params.iter().any(|p| p.target == target);
    for (i, mesh) in scene.meshes.iter().enumerate() {
        let emits = optimised(ParamTarget::Emission { mesh: i }) || mesh.emission.any_positive();
        if emits && !has_area(mesh) {
            out.push(format!("{path}: mesh \"{}\" emits but all its triangles have zero area: it gives no light", mesh.name));
        }
    }
    for mesh in &scene.meshes {
        let material = &scene.materials[mesh.material];
        let alpha = material.alpha.as_ref().and_then(|a| a.value.texture()).map(|t| ("alpha texture", " (it is opaque)", t.uv_set));
        let perturbation = material.perturbation.as_ref().map(|p| (p.what(), "", p.texture().uv_set));
        for (what, consequence, set) in [alpha, perturbation].into_iter().flatten() {
            if !mesh.has_uvs(set) {
                out.push(format!(
                    "{path}: mesh \"{}\" has no texture coordinates: the {what} of its material \"{}\" is not applied to it{consequence}",
                    mesh.name, material.name
                ));
            }
        }
    }
    if !scene.has_light() {
        out.push(format!("{path}: no light (no emitting mesh of non-zero area, no light and no environment): the scene renders black"));
    }
    out
}
