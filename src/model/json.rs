//! The global model's file: [`ImplicitModel`] ↔ `model.json`.
//!
//! Input: a fitted or hand-written model. Output: the JSON document of DESIGN.md,
//!
//! ```text
//! {
//!   "format": "stablesurf.implicit-polynomial",
//!   "version": 1,
//!   "degree": n,
//!   "monomial_order": "graded, x>y>z (Sahin-Unel 6.16)",
//!   "coefficients": [c numbers],
//!   "normalization": {"center": [x, y, z], "scale": s},
//!   "box": {"min": [x, y, z], "max": [x, y, z]},     (when known)
//!   "fit": {...},                                    (FitRecord, when fitted)
//!   "diagnostics": {...}                             (FitDiagnostics, when fitted)
//! }
//! ```
//!
//! where f(p) = Σ_l a_l m_l((p − center)/scale) with the monomials m_l in the order of
//! Sahin & Unel (2008), eq. 6.16. A hand-written model needs only `format`, `version`, `degree`,
//! `coefficients` and `normalization`.
//!
//! Invariants: reading what [`write_model`] wrote gives back an equal model (serde_json prints
//! every `f64` in its shortest form that parses to the same bits, so the round trip is exact);
//! the `fit` and `diagnostics` sections are written with serde from the `poly` types, so fields
//! added there later flow through without changes here. [`read_model`] rejects a file whose
//! coefficient count does not match its degree, whose numbers are not finite or whose scale is
//! not positive, naming the file and the field.

use std::io::Write;
use std::path::Path;

use serde::Serialize;

use super::ModelError;
use crate::cloud::Aabb;
use crate::poly::{n_coefficients, FitDiagnostics, FitRecord, ImplicitModel, ImplicitPolynomial};

/// The value of the `format` field.
pub(crate) const MODEL_FORMAT: &str = "stablesurf.implicit-polynomial";
/// The model-file version this build writes and reads.
pub(crate) const MODEL_VERSION: u32 = 1;
/// The value of the `monomial_order` field.
pub(crate) const MONOMIAL_ORDER: &str = "graded, x>y>z (Sahin-Unel 6.16)";
/// Highest degree a model file may declare (c = 1 771 coefficients at degree 20); a larger
/// declared degree is almost certainly a typing error.
pub(crate) const MAX_DEGREE: u32 = 20;

/// `normalization` of the file.
#[derive(Serialize)]
struct Normalization {
    center: [f64; 3],
    scale: f64,
}

/// The file's layout, field for field (written with serde; read field by field in
/// [`read_model`] so errors can name the field).
#[derive(Serialize)]
struct ModelFile {
    format: String,
    version: u32,
    degree: u32,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    monomial_order: Option<String>,
    coefficients: Vec<f64>,
    normalization: Normalization,
    #[serde(rename = "box", default, skip_serializing_if = "Option::is_none")]
    bounds: Option<Aabb>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    fit: Option<FitRecord>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    diagnostics: Option<FitDiagnostics>,
}

/// Writes `model` as `model.json` (pretty-printed, trailing newline) to `out`.
///
/// ```
/// use std::path::Path;
/// use stablesurf::model::json::{read_model, write_model};
/// use stablesurf::{ImplicitModel, ImplicitPolynomial};
/// let mut coefficients = vec![0.0; 10];
/// coefficients[0] = -1.0;
/// coefficients[4] = 1.0;
/// coefficients[7] = 1.0;
/// coefficients[9] = 1.0 / 3.0;
/// let poly = ImplicitPolynomial { degree: 2, coefficients, center: [0.1, 0.2, 0.3], scale: 0.7 };
/// let model = ImplicitModel { polynomial: poly, bounds: None, fit: None, diagnostics: None };
/// let mut bytes = Vec::new();
/// write_model(&model, &mut bytes).unwrap();
/// assert_eq!(read_model(&bytes, Path::new("model.json")).unwrap(), model);
/// ```
///
/// # Errors
/// [`ModelError::Value`] when the model holds a non-finite number or an inconsistent
/// coefficient count (JSON cannot hold NaN or infinity, so such a model would not read back);
/// [`ModelError::Write`] when `out` fails.
pub fn write_model(model: &ImplicitModel, out: &mut impl Write) -> Result<(), ModelError> {
    check_polynomial(&model.polynomial, model.bounds.as_ref()).map_err(ModelError::Value)?;
    let p = &model.polynomial;
    let file = ModelFile {
        format: MODEL_FORMAT.into(),
        version: MODEL_VERSION,
        degree: p.degree,
        monomial_order: Some(MONOMIAL_ORDER.into()),
        coefficients: p.coefficients.clone(),
        normalization: Normalization {
            center: p.center,
            scale: p.scale,
        },
        bounds: model.bounds,
        fit: model.fit.clone(),
        diagnostics: model.diagnostics.clone(),
    };
    let mut bytes = serde_json::to_vec_pretty(&file)
        .map_err(|e| ModelError::Value(format!("cannot serialize: {e}")))?;
    bytes.push(b'\n');
    // serde_json writes NaN and infinity as `null`, which would not read back: refuse to write a
    // model that does not survive its own round trip rather than write a file that fails later.
    match read_model(&bytes, Path::new("model.json")) {
        Ok(back) if back == *model => {}
        _ => {
            return Err(ModelError::Value(
                "the fit record or diagnostics hold a non-finite number (NaN or infinity), \
                 which JSON cannot store; make the fit report finite values"
                    .into(),
            ))
        }
    }
    out.write_all(&bytes).map_err(ModelError::Write)
}

/// Reads a model from the bytes of `model.json`; `path` only names the file in errors.
///
/// ```
/// use std::path::Path;
/// use stablesurf::model::json::read_model;
/// let text = r#"{"format": "stablesurf.implicit-polynomial", "version": 1, "degree": 2,
///   "coefficients": [-1, 0, 0, 0, 1, 0, 0, 1, 0, 1],
///   "normalization": {"center": [0, 0, 0], "scale": 1}}"#;
/// let model = read_model(text.as_bytes(), Path::new("sphere.json")).unwrap();
/// assert_eq!(model.polynomial.eval([0.0, 0.0, 2.0]), 3.0);
/// assert!(model.bounds.is_none() && model.fit.is_none());
///
/// let wrong = text.replace("[-1, 0,", "[0,");
/// let err = read_model(wrong.as_bytes(), Path::new("sphere.json")).unwrap_err();
/// assert!(err.to_string().contains("sphere.json") && err.to_string().contains("10 coefficients"));
/// ```
///
/// # Errors
/// [`ModelError::Read`], naming `path`, when the bytes are not JSON, a required field is
/// missing, `format` or `version` is not this build's, the degree exceeds `MAX_DEGREE`, the
/// coefficient count is not (n+1)(n+2)(n+3)/6, a number is not finite, or the scale is not
/// positive.
pub fn read_model(bytes: &[u8], path: &Path) -> Result<ImplicitModel, ModelError> {
    let fail = |reason: String| ModelError::Read {
        path: path.display().to_string(),
        reason,
    };
    // serde_json checks the syntax (its errors give line and column); the values are then taken
    // from `parse_exact`, whose numbers are correctly rounded (serde_json's default float parser
    // may be off by one unit in the last place, which would break the exact round trip).
    serde_json::from_slice::<serde::de::IgnoredAny>(bytes)
        .map_err(|e| fail(format!("not valid JSON: {e}")))?;
    let value = parse_exact(bytes).ok_or_else(|| fail("not valid JSON".into()))?;
    let obj = value
        .as_object()
        .ok_or_else(|| fail("the top level is not a JSON object".into()))?;
    // Check the format and version first so a different file type gets a clear message rather
    // than a complaint about a missing field.
    match obj.get("format").and_then(|f| f.as_str()) {
        Some(MODEL_FORMAT) => {}
        Some(other) => {
            return Err(fail(format!(
                "format is \"{other}\", expected \"{MODEL_FORMAT}\""
            )))
        }
        None => return Err(fail(format!("no \"format\": \"{MODEL_FORMAT}\" field"))),
    }
    match obj.get("version").and_then(|v| v.as_u64()) {
        Some(v) if v == u64::from(MODEL_VERSION) => {}
        Some(v) => {
            return Err(fail(format!(
                "version {v} is not supported (this build reads version {MODEL_VERSION})"
            )))
        }
        None => return Err(fail("no integer \"version\" field".into())),
    }
    let degree: u32 = required(obj, "degree", "").map_err(fail)?;
    if degree > MAX_DEGREE {
        return Err(fail(format!(
            "degree {degree} exceeds the maximum {MAX_DEGREE}"
        )));
    }
    let coefficients: Vec<f64> = required(obj, "coefficients", "").map_err(fail)?;
    let normalization: &serde_json::Map<String, serde_json::Value> = obj
        .get("normalization")
        .and_then(|n| n.as_object())
        .ok_or_else(|| fail("no \"normalization\": {\"center\", \"scale\"} object".into()))?;
    let center: [f64; 3] = required(normalization, "center", "normalization.").map_err(fail)?;
    let scale: f64 = required(normalization, "scale", "normalization.").map_err(fail)?;
    let bounds: Option<Aabb> = optional(obj, "box").map_err(fail)?;
    let fit: Option<FitRecord> = optional(obj, "fit").map_err(fail)?;
    let diagnostics: Option<FitDiagnostics> = optional(obj, "diagnostics").map_err(fail)?;
    let polynomial = ImplicitPolynomial {
        degree,
        coefficients,
        center,
        scale,
    };
    check_polynomial(&polynomial, bounds.as_ref()).map_err(fail)?;
    Ok(ImplicitModel {
        polynomial,
        bounds,
        fit,
        diagnostics,
    })
}

type JsonObject = serde_json::Map<String, serde_json::Value>;

/// The field `name` of `obj`, deserialized; errors name it as `prefix` + `name`.
fn required<T: serde::de::DeserializeOwned>(
    obj: &JsonObject,
    name: &str,
    prefix: &str,
) -> Result<T, String> {
    let value = obj
        .get(name)
        .ok_or_else(|| format!("missing field \"{prefix}{name}\""))?;
    T::deserialize(value).map_err(|e| format!("field \"{prefix}{name}\": {e}"))
}

/// The optional field `name` of `obj` (absent or null is `None`).
fn optional<T: serde::de::DeserializeOwned>(
    obj: &JsonObject,
    name: &str,
) -> Result<Option<T>, String> {
    match obj.get(name) {
        None | Some(serde_json::Value::Null) => Ok(None),
        Some(value) => T::deserialize(value)
            .map(Some)
            .map_err(|e| format!("field \"{name}\": {e}")),
    }
}

/// Parses syntactically valid JSON into a value whose numbers are correctly rounded (Rust's
/// `f64::from_str`); integers without fraction or exponent stay integers. `None` on bad syntax.
fn parse_exact(bytes: &[u8]) -> Option<serde_json::Value> {
    let mut at = 0;
    let value = parse_value(bytes, &mut at)?;
    skip_ws(bytes, &mut at);
    (at == bytes.len()).then_some(value)
}

fn skip_ws(s: &[u8], at: &mut usize) {
    while s.get(*at).is_some_and(|c| c.is_ascii_whitespace()) {
        *at += 1;
    }
}

fn parse_value(s: &[u8], at: &mut usize) -> Option<serde_json::Value> {
    use serde_json::Value;
    skip_ws(s, at);
    match *s.get(*at)? {
        b'{' => {
            *at += 1;
            let mut map = JsonObject::new();
            skip_ws(s, at);
            if s.get(*at) == Some(&b'}') {
                *at += 1;
                return Some(Value::Object(map));
            }
            loop {
                skip_ws(s, at);
                let key = parse_string(s, at)?;
                skip_ws(s, at);
                (s.get(*at) == Some(&b':')).then_some(())?;
                *at += 1;
                let value = parse_value(s, at)?;
                map.insert(key, value);
                skip_ws(s, at);
                match s.get(*at)? {
                    b',' => *at += 1,
                    b'}' => {
                        *at += 1;
                        return Some(Value::Object(map));
                    }
                    _ => return None,
                }
            }
        }
        b'[' => {
            *at += 1;
            let mut items = Vec::new();
            skip_ws(s, at);
            if s.get(*at) == Some(&b']') {
                *at += 1;
                return Some(Value::Array(items));
            }
            loop {
                items.push(parse_value(s, at)?);
                skip_ws(s, at);
                match s.get(*at)? {
                    b',' => *at += 1,
                    b']' => {
                        *at += 1;
                        return Some(Value::Array(items));
                    }
                    _ => return None,
                }
            }
        }
        b'"' => parse_string(s, at).map(Value::String),
        b't' | b'f' | b'n' => {
            for (word, value) in [
                ("true", Value::Bool(true)),
                ("false", Value::Bool(false)),
                ("null", Value::Null),
            ] {
                if s[*at..].starts_with(word.as_bytes()) {
                    *at += word.len();
                    return Some(value);
                }
            }
            None
        }
        _ => {
            let start = *at;
            while s
                .get(*at)
                .is_some_and(|c| matches!(c, b'-' | b'+' | b'.' | b'e' | b'E' | b'0'..=b'9'))
            {
                *at += 1;
            }
            let text = std::str::from_utf8(&s[start..*at]).ok()?;
            if !text.contains(['.', 'e', 'E']) {
                if let Ok(v) = text.parse::<u64>() {
                    return Some(Value::from(v));
                }
                if let Ok(v) = text.parse::<i64>() {
                    return Some(Value::from(v));
                }
            }
            serde_json::Number::from_f64(text.parse::<f64>().ok()?).map(Value::Number)
        }
    }
}

/// A JSON string token starting at `at` (a quote), unescaped by serde_json.
fn parse_string(s: &[u8], at: &mut usize) -> Option<String> {
    (s.get(*at) == Some(&b'"')).then_some(())?;
    let start = *at;
    *at += 1;
    loop {
        match *s.get(*at)? {
            b'\\' => *at += 2,
            b'"' => {
                *at += 1;
                return serde_json::from_slice(&s[start..*at]).ok();
            }
            _ => *at += 1,
        }
    }
}

/// Checks the invariants of a polynomial and its box; the error says what is wrong.
fn check_polynomial(p: &ImplicitPolynomial, bounds: Option<&Aabb>) -> Result<(), String> {
    let expected = n_coefficients(p.degree);
    if p.coefficients.len() != expected {
        return Err(format!(
            "degree {} needs {expected} coefficients, found {}",
            p.degree,
            p.coefficients.len()
        ));
    }
    if let Some(l) = p.coefficients.iter().position(|c| !c.is_finite()) {
        return Err(format!("coefficient {l} (0-based) is not a finite number"));
    }
    if p.coefficients.iter().all(|&c| c == 0.0) {
        return Err("all coefficients are zero, which describes no surface".into());
    }
    if !p.center.iter().all(|c| c.is_finite()) {
        return Err("normalization.center is not finite".into());
    }
    if !(p.scale.is_finite() && p.scale > 0.0) {
        return Err(format!(
            "normalization.scale is {}, it must be a finite number > 0",
            p.scale
        ));
    }
    if let Some(b) = bounds {
        let finite = b.min.iter().chain(&b.max).all(|c| c.is_finite());
        if !finite || (0..3).any(|a| b.min[a] > b.max[a]) {
            return Err("box.min and box.max must be finite with min ≤ max on every axis".into());
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_model() -> ImplicitModel {
        let c = n_coefficients(4);
        let coefficients = (0..c)
            .map(|l| ((l as f64) * 0.731).sin() / 3.0 + 1e-17 * l as f64)
            .collect();
        ImplicitModel {
            polynomial: ImplicitPolynomial {
                degree: 4,
                coefficients,
                center: [0.1, -2.0 / 3.0, 1e300],
                scale: std::f64::consts::PI,
            },
            bounds: Some(Aabb {
                min: [-1.0, -2.0, -3.0],
                max: [0.1, 0.2, 0.30000000000000004],
            }),
            fit: Some(FitRecord {
                method: "3lrr".into(),
                epsilon: 0.05,
                kappa: 1.2e-3,
                kappa_rule: "stable".into(),
                n_points: 12345,
            }),
            diagnostics: Some(FitDiagnostics {
                condition_number: 1.5e9,
                leading_form_min_relative: 0.0123,
                bounded: true,
                containment_radius: Some(2.5),
                mean_distance: 1e-3,
                max_distance: 5e-3,
                mean_distance_relative: 1e-4,
                max_distance_relative: 5e-4,
                warnings: vec!["a \"quoted\" warning".into()],
                ..Default::default()
            }),
        }
    }

    #[test]
    fn round_trip_is_exact() {
        let model = sample_model();
        let mut bytes = Vec::new();
        write_model(&model, &mut bytes).unwrap();
        let back = read_model(&bytes, Path::new("m.json")).unwrap();
        assert_eq!(back, model);
        for (a, b) in back
            .polynomial
            .coefficients
            .iter()
            .zip(&model.polynomial.coefficients)
        {
            assert_eq!(a.to_bits(), b.to_bits());
        }
        let text = String::from_utf8(bytes.clone()).unwrap();
        assert!(text.contains("\"monomial_order\": \"graded, x>y>z (Sahin-Unel 6.16)\""));
        assert!(text.contains("\"box\""));
        // Writing what was read gives the same bytes.
        let mut again = Vec::new();
        write_model(&back, &mut again).unwrap();
        assert_eq!(again, bytes);
    }

    #[test]
    fn bad_models_are_rejected_with_the_file_name() {
        let good = r#"{"format": "stablesurf.implicit-polynomial", "version": 1, "degree": 2,
            "coefficients": [-1, 0, 0, 0, 1, 0, 0, 1, 0, 1],
            "normalization": {"center": [0, 0, 0], "scale": 1}}"#;
        assert!(read_model(good.as_bytes(), Path::new("x.json")).is_ok());
        let cases = [
            (good.replace("\"scale\": 1", "\"scale\": 0"), "scale"),
            (good.replace("\"scale\": 1", "\"scale\": -2"), "scale"),
            (
                good.replace("\"degree\": 2", "\"degree\": 3"),
                "20 coefficients",
            ),
            (
                good.replace("\"version\": 1", "\"version\": 7"),
                "version 7",
            ),
            (good.replace("implicit-polynomial", "mesh"), "format"),
            (good.replace("[-1, 0,", "[1e999, 0,"), "JSON"),
            (good.replace(", \"scale\": 1", ""), "scale"),
            (good.replace("[0, 0, 0]", "[0, 0]"), "center"),
            (good[..40].to_string(), "JSON"),
            (
                good.replace(
                    "[-1, 0, 0, 0, 1, 0, 0, 1, 0, 1]",
                    "[0, 0, 0, 0, 0, 0, 0, 0, 0, 0]",
                ),
                "zero",
            ),
        ];
        for (text, needle) in cases {
            let err = read_model(text.as_bytes(), Path::new("dir/x.json")).unwrap_err();
            let msg = err.to_string();
            assert!(msg.contains("dir/x.json"), "{msg}");
            assert!(msg.contains(needle), "expected {needle:?} in {msg}");
        }
    }

    #[test]
    fn non_finite_values_are_refused_on_write() {
        let mut m = sample_model();
        m.polynomial.coefficients[3] = f64::NAN;
        assert!(matches!(
            write_model(&m, &mut Vec::new()),
            Err(ModelError::Value(_))
        ));
        let mut m = sample_model();
        if let Some(d) = m.diagnostics.as_mut() {
            d.condition_number = f64::INFINITY;
        }
        let mut out = Vec::new();
        assert!(matches!(
            write_model(&m, &mut out),
            Err(ModelError::Value(_))
        ));
        assert!(out.is_empty());
    }
}
