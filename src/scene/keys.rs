//! The keys a scene file accepts, read from the loader's own serde types: a deserializer
//! that builds each type from made-up values and records, for every struct it is asked
//! for, the field names that serde passes to `deserialize_struct` (the names
//! `deny_unknown_fields` checks), under the section's path (a camera's keys under
//! `sensors`, a normal map's under `materials.normal_map`). The `[optimise]` table is read
//! by hand ([`crate::settings::deserialize_table`]); its keys are its own keys and the run
//! settings, the same lists its reader accepts.

use std::cell::RefCell;
use std::collections::BTreeSet;
use std::fmt;

use serde::de::value::{MapDeserializer, SeqDeserializer, StrDeserializer};
use serde::de::{self, DeserializeSeed, Deserializer, EnumAccess, MapAccess, SeqAccess, VariantAccess, Visitor};
use serde::Deserialize;

use super::file::{ParamFile, SceneFile, TextureRef};
use crate::settings::{OptimiseTable, Settings, SettingsTable};

/// The section of the texture reference `{ texture = "file.exr", filter = …, wrap = … }`,
/// which every colour or number that may be a texture accepts.
pub const TEXTURE_SECTION: &str = "texture";

/// Every key a scene file accepts, as (section, key): the section is the table's path
/// without array indices (`""` for the top level, `sensors`, `materials.normal_map`,
/// `optimise.params`, [`TEXTURE_SECTION`]). Which material types take which material
/// keys is [`super::MaterialKind::accepts`].
///
/// ```
/// let keys = vkinverse::scene::scene_keys();
/// assert!(keys.contains(&("sensors".to_string(), "fov_y")));
/// assert!(keys.contains(&("optimise".to_string(), "spp")));
/// ```
pub fn scene_keys() -> BTreeSet<(String, &'static str)> {
    let mut keys = probe::<SceneFile>("");
    // The only table read by hand is `[optimise]`: its own keys and every run setting.
    keys.extend(<OptimiseTable<ParamFile> as SettingsTable>::OWN_KEYS.iter().chain(Settings::KEYS).map(|k| ("optimise".to_string(), *k)));
    keys.extend(probe::<ParamFile>("optimise.params"));
    keys.extend(probe::<TextureRef>(TEXTURE_SECTION));
    keys
}

/// The keys of `T` and of every struct inside it, with `T` at section `root`. A value that
/// may take several shapes (an untagged enum: a colour or a texture) is built from each
/// shape in turn until one fits; its own keys are not followed (texture references are
/// listed once, by [`scene_keys`]).
fn probe<T: for<'de> Deserialize<'de>>(root: &str) -> BTreeSet<(String, &'static str)> {
    let state = RefCell::new(State::default());
    loop {
        state.borrow_mut().last_any = None;
        let result = T::deserialize(Probe { path: root.to_string(), state: &state });
        let mut s = state.borrow_mut();
        if result.is_ok() {
            let maps: Vec<&String> = s.maps.iter().filter(|p| p.as_str() != "optimise").collect();
            assert!(maps.is_empty(), "tables read by hand at {maps:?}: scene_keys cannot list their keys");
            return std::mem::take(&mut s.keys);
        }
        // The last value of several shapes was the one that did not fit: try its next shape.
        let Some(path) = s.last_any.take() else { panic!("{root}: {}", result.err().map(|e| e.0).unwrap_or_default()) };
        let shape = s.shapes.entry(path.clone()).or_default();
        *shape += 1;
        assert!(*shape < SHAPES, "{path}: no value fits ({})", result.err().map(|e| e.0).unwrap_or_default());
    }
}

/// How many shapes [`Probe::deserialize_any`] offers: a number, three numbers, a string, a
/// texture reference.
const SHAPES: usize = 4;

#[derive(Default)]
struct State {
    keys: BTreeSet<(String, &'static str)>,
    /// The shape each untagged value's path takes next.
    shapes: std::collections::BTreeMap<String, usize>,
    last_any: Option<String>,
    /// Paths of tables deserialized as maps (whose keys serde does not name).
    maps: BTreeSet<String>,
}

#[derive(Debug)]
struct ProbeError(String);

impl fmt::Display for ProbeError {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ProbeError {}

impl de::Error for ProbeError {
    fn custom<T: fmt::Display>(msg: T) -> Self {
        Self(msg.to_string())
    }
}

/// A deserializer that gives every value a plausible content and records struct fields.
struct Probe<'s> {
    path: String,
    state: &'s RefCell<State>,
}

impl<'s> Probe<'s> {
    fn at(&self, key: &str) -> Probe<'s> {
        let path = if self.path.is_empty() { key.to_string() } else { format!("{}.{key}", self.path) };
        Probe { path, state: self.state }
    }
}

type Result<T> = std::result::Result<T, ProbeError>;

impl<'de> Deserializer<'de> for Probe<'_> {
    type Error = ProbeError;

    fn deserialize_any<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        let shape = self.state.borrow().shapes.get(&self.path).copied().unwrap_or(0);
        self.state.borrow_mut().last_any = Some(self.path);
        match shape {
            0 => v.visit_f64(1.0),
            1 => v.visit_seq(SeqDeserializer::<_, ProbeError>::new([1.0f64; 3].into_iter())),
            2 => v.visit_str(""),
            _ => v.visit_map(MapDeserializer::<_, ProbeError>::new([("texture", "")].into_iter())),
        }
    }
    fn deserialize_bool<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_bool(false)
    }
    fn deserialize_i8<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_i16<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_i32<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_i64<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_u8<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_u16<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_u32<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_u64<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_u64(1)
    }
    fn deserialize_f32<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_f64(1.0)
    }
    fn deserialize_f64<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_f64(1.0)
    }
    fn deserialize_char<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_char('a')
    }
    fn deserialize_str<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_str("")
    }
    fn deserialize_string<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_str("")
    }
    fn deserialize_bytes<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_bytes(&[])
    }
    fn deserialize_byte_buf<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_bytes(&[])
    }
    fn deserialize_option<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_some(self)
    }
    fn deserialize_unit<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_unit()
    }
    fn deserialize_unit_struct<V: Visitor<'de>>(self, _name: &'static str, v: V) -> Result<V::Value> {
        v.visit_unit()
    }
    fn deserialize_newtype_struct<V: Visitor<'de>>(self, _name: &'static str, v: V) -> Result<V::Value> {
        v.visit_newtype_struct(self)
    }
    fn deserialize_seq<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_seq(Elements { probe: self, left: 1 })
    }
    fn deserialize_tuple<V: Visitor<'de>>(self, len: usize, v: V) -> Result<V::Value> {
        v.visit_seq(Elements { probe: self, left: len })
    }
    fn deserialize_tuple_struct<V: Visitor<'de>>(self, _name: &'static str, len: usize, v: V) -> Result<V::Value> {
        v.visit_seq(Elements { probe: self, left: len })
    }
    fn deserialize_map<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        self.state.borrow_mut().maps.insert(self.path);
        v.visit_map(MapDeserializer::<_, ProbeError>::new(std::iter::empty::<(&str, &str)>()))
    }
    fn deserialize_struct<V: Visitor<'de>>(self, _name: &'static str, fields: &'static [&'static str], v: V) -> Result<V::Value> {
        self.state.borrow_mut().keys.extend(fields.iter().map(|f| (self.path.clone(), *f)));
        v.visit_map(Fields { probe: self, fields, next: 0 })
    }
    fn deserialize_enum<V: Visitor<'de>>(self, _name: &'static str, variants: &'static [&'static str], v: V) -> Result<V::Value> {
        v.visit_enum(Variant { probe: self, name: variants.first().copied().unwrap_or_default() })
    }
    fn deserialize_identifier<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_str("")
    }
    fn deserialize_ignored_any<V: Visitor<'de>>(self, v: V) -> Result<V::Value> {
        v.visit_unit()
    }
}

/// A sequence of `left` values, each probed at the sequence's own path.
struct Elements<'s> {
    probe: Probe<'s>,
    left: usize,
}

impl<'de> SeqAccess<'de> for Elements<'_> {
    type Error = ProbeError;
    fn next_element_seed<T: DeserializeSeed<'de>>(&mut self, seed: T) -> Result<Option<T::Value>> {
        if self.left == 0 {
            return Ok(None);
        }
        self.left -= 1;
        seed.deserialize(Probe { path: self.probe.path.clone(), state: self.probe.state }).map(Some)
    }
}

/// A struct's table with every field present, each probed at its own path.
struct Fields<'s> {
    probe: Probe<'s>,
    fields: &'static [&'static str],
    next: usize,
}

impl<'de> MapAccess<'de> for Fields<'_> {
    type Error = ProbeError;
    fn next_key_seed<K: DeserializeSeed<'de>>(&mut self, seed: K) -> Result<Option<K::Value>> {
        match self.fields.get(self.next) {
            Some(field) => seed.deserialize(StrDeserializer::<ProbeError>::new(field)).map(Some),
            None => Ok(None),
        }
    }
    fn next_value_seed<V: DeserializeSeed<'de>>(&mut self, seed: V) -> Result<V::Value> {
        let field = self.fields[self.next];
        self.next += 1;
        seed.deserialize(self.probe.at(field))
    }
}

/// An enum's first variant.
struct Variant<'s> {
    probe: Probe<'s>,
    name: &'static str,
}

impl<'de, 's> EnumAccess<'de> for Variant<'s> {
    type Error = ProbeError;
    type Variant = Probe<'s>;
    fn variant_seed<V: DeserializeSeed<'de>>(self, seed: V) -> Result<(V::Value, Probe<'s>)> {
        let value = seed.deserialize(StrDeserializer::<ProbeError>::new(self.name))?;
        Ok((value, self.probe))
    }
}

impl<'de> VariantAccess<'de> for Probe<'_> {
    type Error = ProbeError;
    fn unit_variant(self) -> Result<()> {
        Ok(())
    }
    fn newtype_variant_seed<T: DeserializeSeed<'de>>(self, seed: T) -> Result<T::Value> {
        seed.deserialize(self)
    }
    fn tuple_variant<V: Visitor<'de>>(self, len: usize, v: V) -> Result<V::Value> {
        self.deserialize_tuple(len, v)
    }
    fn struct_variant<V: Visitor<'de>>(self, fields: &'static [&'static str], v: V) -> Result<V::Value> {
        self.deserialize_struct("", fields, v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_cover_every_section_of_the_scene_file() {
        let keys = scene_keys();
        for (section, key) in [
            ("", "import"),
            ("film", "filter_radius"),
            ("integrator", "hide_emitters"),
            ("sensors", "aperture_radius"),
            ("materials", "base_color"),
            ("materials.normal_map", "bitangent"),
            ("materials.bump_map", "scale"),
            ("meshes", "two_sided"),
            ("lights", "falloff"),
            ("environment", "scale"),
            ("media", "density"),
            ("optimise", "params"),
            ("optimise", "fd_two_trace"),
            ("optimise.params", "init"),
            (TEXTURE_SECTION, "wrap"),
        ] {
            assert!(keys.contains(&(section.to_string(), key)), "{section}.{key} in {keys:?}");
        }
        let sections: BTreeSet<&str> = keys.iter().map(|(s, _)| s.as_str()).collect();
        assert_eq!(sections.len(), 14, "{sections:?}");
    }
}
