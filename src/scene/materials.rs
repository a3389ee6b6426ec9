//! Scene materials: a body's reflectance model, from its `[body.material]` table with a
//! band's overrides merged in.
//!
//! In: a [`Scene`], a body index and a band name. Out: a [`Material`] (Lambert,
//! Lommel–Seeliger or Hapke with its parameters); errors name the key that is wrong.

use super::Scene;
use crate::error::Result;
use crate::photometry::hapke::HFunction;
use crate::photometry::Material;

impl Scene {
    /// Body `i`'s material in `band` (None: the base parameters): its `[body.material]`
    /// table with the band's overrides applied. Errors name the key.
    pub fn material(&self, i: usize, band: Option<&str>) -> Result<Material> {
        let key = format!("body[{i}].material");
        let table = self.bodies[i]
            .material
            .as_ref()
            .ok_or_else(|| self.err(&key, "missing: give the body a reflectance model"))?;
        let mut merged = table.clone();
        let overrides = match merged.remove("bands") {
            Some(toml::Value::Table(t)) => t,
            Some(_) => return Err(self.err(format!("{key}.bands"), "must be a table of bands")),
            None => toml::Table::new(),
        };
        for name in overrides.keys() {
            if !self.bands.iter().any(|b| &b.name == name) {
                return Err(self.err(format!("{key}.bands.{name}"), "no [[band]] has this name"));
            }
        }
        // Each entry keeps the key path it came from, for error messages.
        let mut entries: Vec<(String, toml::Value, String)> = merged
            .into_iter()
            .map(|(k, v)| (k, v, key.clone()))
            .collect();
        if let Some(name) = band {
            let band_key = format!("{key}.bands.{name}");
            let band_table = match overrides.get(name) {
                Some(toml::Value::Table(t)) => t.clone(),
                Some(_) => return Err(self.err(band_key, "must be a table of parameters")),
                None => toml::Table::new(),
            };
            for (k, v) in band_table {
                if k == "model" || k == "bands" {
                    return Err(self.err(
                        format!("{band_key}.{k}"),
                        "a band may change parameters, not the model",
                    ));
                }
                entries.retain(|e| e.0 != k);
                entries.push((k, v, band_key.clone()));
            }
        }
        self.material_from_entries(&key, entries)
    }

    /// A material from `model`, `h_function` and numeric parameter entries.
    fn material_from_entries(
        &self,
        key: &str,
        entries: Vec<(String, toml::Value, String)>,
    ) -> Result<Material> {
        let mut model = None;
        let mut h_function = None;
        let mut params = Vec::new();
        for (k, v, from) in entries {
            let at = format!("{from}.{k}");
            match (k.as_str(), v) {
                ("model", toml::Value::String(m)) => model = Some(m),
                ("h_function", toml::Value::String(f)) => {
                    h_function = Some(match f.as_str() {
                        "1981" => HFunction::Hapke1981,
                        "2002" => HFunction::Hapke2002,
                        other => {
                            return Err(self.err(at, format!("'{other}': use \"1981\" or \"2002\"")))
                        }
                    })
                }
                (_, toml::Value::Float(x)) => params.push((k, x, at)),
                (_, toml::Value::Integer(x)) => params.push((k, x as f64, at)),
                (_, other) => {
                    return Err(
                        self.err(at, format!("must be a number, not a {}", other.type_str()))
                    )
                }
            }
        }
        let model = model.ok_or_else(|| {
            self.err(
                format!("{key}.model"),
                format!("missing: one of {}", Material::MODELS.join(", ")),
            )
        })?;
        let named: Vec<(String, f64)> = params.iter().map(|(k, x, _)| (k.clone(), *x)).collect();
        Material::from_params(&model, &named, h_function).map_err(|e| {
            // Point at the parameter the message names, else at the material.
            let at = params
                .iter()
                .find(|(k, _, _)| {
                    e.to_string().contains(&format!("'{k}'"))
                        || e.to_string().contains(&format!(" {k} ="))
                })
                .map_or(format!("{key}.model"), |(_, _, at)| at.clone());
            self.err(at, e.to_string())
        })
    }
}
