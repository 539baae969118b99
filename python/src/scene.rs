//! `ecp.Scene`: a validated scene, from a TOML file, TOML text or a Python dict with the keys of
//! the scene format (`docs/scene-format.md`), checked by the same code and with the same error
//! messages as `ecp check`.

use std::path::{Path, PathBuf};

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyBool, PyDict, PyFloat, PyInt, PyList, PyString, PyTuple};

use ecp::error::InputErrorKind;
use ecp::scene::{SceneFile, load_scene, parse_scene};
use ecp_formulations::sensitivity::Param;

use crate::convert::type_name;
use crate::errors::{argument, guard, input};

/// A validated scene: bodies, half-spaces, friction, step, solver and formulation.
///
/// Build one with :meth:`Scene.from_toml`, :meth:`Scene.from_string` or :meth:`Scene.from_dict`.
/// Scenes are values: :meth:`with_params` returns a changed copy. They pickle (for Ray and
/// multiprocessing) as their TOML text, their path and the parameters set since.
#[pyclass(module = "ecp", name = "Scene", frozen)]
#[derive(Clone)]
pub struct Scene {
    pub(crate) file: SceneFile,
    /// The TOML text the scene was parsed from (generated for a dict).
    text: String,
    /// Parameters set after parsing, in order (replayed when unpickled).
    overrides: Vec<(String, f64)>,
}

impl Scene {
    fn parse(text: String, path: &Path, from_dict: bool) -> PyResult<Scene> {
        let file = parse_scene(&text, path).map_err(|mut e| {
            if from_dict {
                // The line is one of the generated TOML text, not of anything the caller wrote.
                e.line = None;
            }
            input(e)
        })?;
        Ok(Scene {
            file,
            text,
            overrides: Vec::new(),
        })
    }

    /// A copy with the parameters set (each checked as the scene checks it).
    pub(crate) fn with(&self, values: &[(Param, f64)]) -> PyResult<Scene> {
        let mut scene = self.clone();
        for (param, value) in values {
            param
                .set(&mut scene.file.scene, *value)
                .map_err(|e| argument("params", InputErrorKind::InvalidValue, e.to_string()))?;
            scene.overrides.push((param.to_string(), *value));
        }
        Ok(scene)
    }
}

/// A parameter name (`mu`, `e_r`, `mass`, `mass[1]`, `vx0`, `fx`, ...) checked against `scene`.
pub(crate) fn param(name: &str, scene: &ecp_formulations::Scene) -> PyResult<Param> {
    let p: Param = name
        .parse()
        .map_err(|e| argument("params", InputErrorKind::UnknownName, format!("{e}")))?;
    p.get(scene)
        .map_err(|e| argument("params", InputErrorKind::InvalidValue, format!("{e}")))?;
    Ok(p)
}

/// `{name: value}` pairs of a dict, in its order, as checked parameters.
pub(crate) fn param_values(
    values: &Bound<'_, PyDict>,
    scene: &ecp_formulations::Scene,
) -> PyResult<Vec<(Param, f64)>> {
    let mut out = Vec::with_capacity(values.len());
    for (k, v) in values.iter() {
        let name: String = k
            .extract()
            .map_err(|_| PyTypeError::new_err("parameter names must be strings such as \"mu\""))?;
        let value: f64 = v.extract().map_err(|_| {
            PyTypeError::new_err(format!(
                "parameter {name}: expected a number, got {}",
                type_name(&v)
            ))
        })?;
        out.push((param(&name, scene)?, value));
    }
    Ok(out)
}

#[pymethods]
impl Scene {
    /// Reads and validates the scene file at ``path`` (TOML, ``docs/scene-format.md``).
    ///
    /// Raises :class:`ecp.InputError` with the file, key and line of the problem, as
    /// ``ecp check`` prints it.
    #[staticmethod]
    fn from_toml(py: Python<'_>, path: PathBuf) -> PyResult<Scene> {
        let (file, text) = guard(|| {
            py.detach(|| {
                let file = load_scene(&path)?;
                // Kept for pickling; the file was just read.
                let text = std::fs::read_to_string(&path).unwrap_or_default();
                Ok::<_, ecp::error::InputError>((file, text))
            })
            .map_err(input)
        })?;
        Ok(Scene {
            file,
            text,
            overrides: Vec::new(),
        })
    }

    /// Parses scene TOML text; ``path`` names it in messages, and relative mesh paths are
    /// resolved against its directory.
    #[staticmethod]
    #[pyo3(signature = (text, path = None))]
    fn from_string(text: String, path: Option<PathBuf>) -> PyResult<Scene> {
        let path = path.unwrap_or_else(|| PathBuf::from("<string>"));
        guard(|| Scene::parse(text, &path, false))
    }

    /// A scene from a dict with the keys of a scene file: ``{"simulation": {"h": 0.01, ...},
    /// "friction": {...}, "half_spaces": [...], "bodies": [{..., "pieces": [...]}]}``. Values
    /// may be numbers, strings, lists, tuples, numpy arrays and dicts; ``None`` leaves a key
    /// out. Checked as a file is, with the same messages (the key path, no line number);
    /// relative mesh paths are resolved against ``base_dir`` (default: the working directory).
    #[staticmethod]
    #[pyo3(signature = (data, base_dir = None))]
    fn from_dict(data: &Bound<'_, PyAny>, base_dir: Option<PathBuf>) -> PyResult<Scene> {
        let dict = data.cast::<PyDict>().map_err(|_| {
            PyTypeError::new_err(format!(
                "Scene.from_dict takes a dict with the keys of a scene file, got {}",
                type_name(data)
            ))
        })?;
        let table = dict_to_table(dict, "")?;
        let text = toml::to_string(&table).map_err(|e| {
            argument(
                "data",
                InputErrorKind::WrongType,
                format!(
                    "cannot write the dict as a scene ({e}); use numbers, strings, lists and dicts"
                ),
            )
        })?;
        let path = base_dir.unwrap_or_default().join("<dict>");
        guard(|| Scene::parse(text, &path, true))
    }

    /// The scene's name.
    #[getter]
    fn name(&self) -> String {
        self.file.scene.name.clone()
    }

    /// The file the scene was read from (``<dict>`` or ``<string>`` otherwise).
    #[getter]
    fn path(&self) -> PathBuf {
        self.file.path.clone()
    }

    /// Step length h (s).
    #[getter]
    fn h(&self) -> f64 {
        self.file.scene.h
    }

    /// Simulated duration (s).
    #[getter]
    fn duration(&self) -> f64 {
        self.file.scene.duration
    }

    /// Number of steps covering the duration.
    #[getter]
    fn num_steps(&self) -> usize {
        self.file.scene.num_steps()
    }

    /// The body names, in order.
    #[getter]
    fn bodies(&self) -> Vec<String> {
        self.file
            .scene
            .bodies
            .iter()
            .map(|b| b.name.clone())
            .collect()
    }

    /// The scene's formulation (``hull``, ``union``, ``reduced`` or ``point``).
    #[getter]
    fn formulation(&self) -> String {
        self.file.formulation.to_string()
    }

    /// The scene's solver backend (``newton``, ``path`` or ``conic``).
    #[getter]
    fn solver(&self) -> String {
        self.file.solver.name.clone()
    }

    /// The text the scene was parsed from (TOML; generated for a dict). Parameters set with
    /// :meth:`with_params` are not in it.
    #[getter]
    fn toml(&self) -> String {
        self.text.clone()
    }

    /// The value of a parameter: ``mu``, ``e_t``, ``e_o``, ``e_r``, ``mass``, ``i_xx`` ...
    /// ``i_yz``, the initial state ``x0`` ... ``wz0``, a constant load ``fx`` ... ``tz``; a body
    /// other than 0 as ``mass[1]``.
    fn get_param(&self, name: &str) -> PyResult<f64> {
        let p = param(name, &self.file.scene)?;
        p.get(&self.file.scene)
            .map_err(|e| argument("name", InputErrorKind::InvalidValue, e.to_string()))
    }

    /// A copy with parameters set, from a dict and/or keywords:
    /// ``scene.with_params(mu=0.3, e_r=0.05)``, ``scene.with_params({"mass[1]": 2.0})``.
    #[pyo3(signature = (values = None, **kwargs))]
    fn with_params(
        &self,
        values: Option<&Bound<'_, PyDict>>,
        kwargs: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Scene> {
        let mut all = Vec::new();
        for d in [values, kwargs].into_iter().flatten() {
            all.extend(param_values(d, &self.file.scene)?);
        }
        self.with(&all)
    }

    /// What the scene builds, as ``ecp check`` prints it.
    fn describe(&self) -> String {
        ecp::scene::describe(&self.file)
    }

    fn __repr__(&self) -> String {
        let s = &self.file.scene;
        format!(
            "Scene(name={:?}, bodies={}, h={}, duration={}, formulation={:?}, solver={:?})",
            s.name,
            s.bodies.len(),
            s.h,
            s.duration,
            self.file.formulation.as_str(),
            self.file.solver.name
        )
    }

    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyTuple>)> {
        let py = slf.py();
        let this = slf.get();
        let restore = py.import("ecp._ecp")?.getattr("_restore_scene")?;
        let args = PyTuple::new(
            py,
            [
                this.text.clone().into_pyobject(py)?.into_any(),
                this.file.path.clone().into_pyobject(py)?.into_any(),
                this.overrides.clone().into_pyobject(py)?.into_any(),
            ],
        )?;
        Ok((restore, args))
    }
}

/// Rebuilds a pickled [`Scene`].
#[pyfunction]
pub fn _restore_scene(
    text: String,
    path: PathBuf,
    overrides: Vec<(String, f64)>,
) -> PyResult<Scene> {
    let from_dict = path.file_name().is_some_and(|n| n == "<dict>");
    let scene = Scene::parse(text, &path, from_dict)?;
    let mut values = Vec::with_capacity(overrides.len());
    for (name, value) in overrides {
        values.push((param(&name, &scene.file.scene)?, value));
    }
    scene.with(&values)
}

/// A Python dict as a TOML table; `key` is the path so far, for messages.
fn dict_to_table(dict: &Bound<'_, PyDict>, key: &str) -> PyResult<toml::Table> {
    let mut table = toml::Table::new();
    for (k, v) in dict.iter() {
        let name: String = k.extract().map_err(|_| {
            PyTypeError::new_err(format!(
                "key {}: scene keys must be strings, got {}",
                if key.is_empty() { "(top level)" } else { key },
                type_name(&k)
            ))
        })?;
        let path = if key.is_empty() {
            name.clone()
        } else {
            format!("{key}.{name}")
        };
        if let Some(value) = to_toml(&v, &path)? {
            table.insert(name, value);
        }
    }
    Ok(table)
}

/// A Python value as a TOML value (`None` for Python's `None`: the key is left out).
fn to_toml(v: &Bound<'_, PyAny>, key: &str) -> PyResult<Option<toml::Value>> {
    if v.is_none() {
        return Ok(None);
    }
    if v.is_instance_of::<PyBool>() {
        return Ok(Some(toml::Value::Boolean(v.extract()?)));
    }
    if v.is_instance_of::<PyInt>() {
        return match v.extract::<i64>() {
            Ok(i) => Ok(Some(toml::Value::Integer(i))),
            Err(_) => Ok(Some(toml::Value::Float(v.extract()?))),
        };
    }
    if v.is_instance_of::<PyFloat>() {
        return Ok(Some(toml::Value::Float(v.extract()?)));
    }
    if v.is_instance_of::<PyString>() {
        return Ok(Some(toml::Value::String(v.extract()?)));
    }
    if let Ok(d) = v.cast::<PyDict>() {
        return Ok(Some(toml::Value::Table(dict_to_table(d, key)?)));
    }
    let items: Option<Vec<Bound<'_, PyAny>>> =
        if v.is_instance_of::<PyList>() || v.is_instance_of::<PyTuple>() {
            Some(v.try_iter()?.collect::<PyResult<_>>()?)
        } else if v.hasattr("tolist")? && v.hasattr("shape")? {
            // A numpy array or scalar: its Python equivalent.
            let plain = v.call_method0("tolist")?;
            return to_toml(&plain, key);
        } else {
            None
        };
    if let Some(items) = items {
        let mut out = Vec::with_capacity(items.len());
        for (i, item) in items.iter().enumerate() {
            match to_toml(item, &format!("{key}[{i}]"))? {
                Some(value) => out.push(value),
                None => {
                    return Err(PyTypeError::new_err(format!(
                        "key {key}[{i}]: None cannot be an element of a list; give a value"
                    )));
                }
            }
        }
        return Ok(Some(toml::Value::Array(out)));
    }
    // Other numbers (numpy scalars without `tolist`, fractions, ...).
    if let Ok(x) = v.extract::<f64>() {
        return Ok(Some(toml::Value::Float(x)));
    }
    Err(PyTypeError::new_err(format!(
        "key {key}: a value of type {} cannot go into a scene; use numbers, strings, lists and \
         dicts (docs/scene-format.md)",
        type_name(v)
    )))
}
