//! `inference.zarr`: the calibration as ArviZ's InferenceData, in Zarr v3,
//! which xarray opens natively — no glue between `mrbp` and `az.summary`,
//! `az.plot_trace`, `az.loo`:
//!
//! ```python
//! idata = az.InferenceData.from_datatree(xr.open_datatree("…/inference.zarr", engine="zarr"))
//! ```
//!
//! | group | variables | dims |
//! |---|---|---|
//! | `posterior` | every coordinate (SI) | chain (= walker), draw (= step after burn-in) |
//! | `sample_stats` | `lp`, `accepted` | chain, draw |
//! | `log_likelihood` | `tau` | chain, draw (thinned steps), obs |
//! | `posterior_predictive` | `tau` (a replicated record) | chain, draw (thinned steps), obs |
//! | `observed_data` | `tau` | obs |
//!
//! Every observation carries its `run` and `time` as coordinates. The
//! posterior holds exactly the draws of `summary.parquet` (after burn-in,
//! an even number per walker), so `az.summary` gives our mean, sd, ESS and
//! MCSE; its R̂ differs (see [`RHAT_NOTE`]).

use std::path::Path;
use std::sync::Arc;

use serde_json::{json, Map, Value};
use zarrs::array::{data_type, Array, ArrayBuilder, DataType, FillValueMetadata, IntoArrayBytes};
use zarrs::filesystem::FilesystemStore;
use zarrs::group::{Group, GroupBuilder};
use zarrs::storage::ReadableWritableListableStorage;

use crate::error::{Error, Result};
use crate::pointwise::PointwiseDraws;
use crate::posterior::{unit_of, PosteriorSample};
use crate::sampler::diagnostics::analysed_draws;

/// The store's name in a calibration folder.
pub const FILE: &str = "inference.zarr";

/// Why ArviZ's R̂ of this store is not ours, and how to get ours.
pub const RHAT_NOTE: &str =
    "Each chain is one walker of an affine-invariant ensemble. Walkers of an \
ensemble move together and each is short compared with its autocorrelation, so R-hat over walkers \
reads 1.01-1.03 on a converged run. mrbp's R-hat (summary.parquet) compares the independent \
ensembles instead: each ensemble's draws, step by step, as one chain (coordinate `ensemble`). \
ESS, MCSE, mean and sd over walkers are the same as mrbp's.";

/// What the store says of itself, besides the draws.
pub struct StoreInfo<'a> {
    pub calibration_id: &'a str,
    pub burn_in: usize,
    pub ensembles: usize,
    /// The pointwise groups' steps are at least this many steps apart (≈ τ).
    pub stride: usize,
}

/// The values of one array, flat, in C order over its dimensions.
#[derive(Clone, Debug)]
pub enum Values {
    F64(Vec<f64>),
    F32(Vec<f32>),
    I64(Vec<i64>),
    Bool(Vec<bool>),
    Str(Vec<String>),
}

/// One array of a group: a variable, or a coordinate (an array over the
/// one dimension it names, or one a variable's `coordinates` attribute
/// names).
#[derive(Clone, Debug)]
pub struct Node {
    pub name: String,
    /// Its dimensions, with their lengths.
    pub dims: Vec<(&'static str, usize)>,
    pub values: Values,
    pub attrs: Map<String, Value>,
}

/// One group of the InferenceData (`posterior`, `sample_stats`, …).
#[derive(Clone, Debug)]
pub struct DataGroup {
    pub name: &'static str,
    pub attrs: Map<String, Value>,
    pub nodes: Vec<Node>,
}

/// The whole InferenceData, in memory: what `inference.zarr` holds and
/// what the Python package hands to ArviZ without a file between.
#[derive(Clone, Debug)]
pub struct InferenceData {
    pub attrs: Map<String, Value>,
    pub groups: Vec<DataGroup>,
}

/// Writes `data` into `path` (a folder), replacing an earlier store; the
/// store is built beside it and renamed into place.
pub fn write(path: &Path, data: &InferenceData) -> Result<()> {
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let tmp = tempfile::Builder::new()
        .prefix(crate::atomic::TEMPORARY)
        .suffix(".zarr.tmp")
        .tempdir_in(parent)
        .map_err(|e| Error::output(parent, e))?;
    build(tmp.path(), data).map_err(|e| Error::output(path, e))?;
    crate::atomic::replace_dir(&tmp.keep(), path)
}

type Failure = Box<dyn std::error::Error>;

/// What a store holds, read back: its calibration, the posterior draws by
/// coordinate name (`[chain][draw]`), and the pointwise log-likelihood
/// (`[chain][draw][obs]`) with its shape.
#[derive(Clone, Debug, PartialEq)]
pub struct Stored {
    pub calibration_id: String,
    /// The steps of the posterior's draws.
    pub draws: Vec<i64>,
    pub posterior: Vec<(String, Vec<f64>)>,
    pub log_likelihood: Vec<f64>,
    /// (chains, draws, observations) of the pointwise groups.
    pub pointwise_shape: (usize, usize, usize),
}

/// The calibration the store at `path` was derived from (its root's
/// `calibration_id` attribute).
pub fn calibration_id(path: &Path) -> Result<String> {
    let meta = path.join("zarr.json");
    let text = std::fs::read_to_string(&meta)
        .map_err(|e| Error::input(&meta, format!("cannot read: {e}")))?;
    let json: Value = serde_json::from_str(&text)
        .map_err(|e| Error::input(&meta, format!("not a Zarr group: {e}")))?;
    Ok(json
        .pointer("/attributes/calibration_id")
        .and_then(Value::as_str)
        .unwrap_or_default()
        .to_string())
}

/// Reads the store at `path` (written by [`write`]).
pub fn read(path: &Path) -> Result<Stored> {
    read_store(path).map_err(|e| Error::input(path, format!("not a readable inference.zarr: {e}")))
}

fn read_store(path: &Path) -> std::result::Result<Stored, Failure> {
    let store: ReadableWritableListableStorage = Arc::new(FilesystemStore::new(path)?);
    let root = Group::open(store.clone(), "/")?;
    let calibration_id = root
        .attributes()
        .get("calibration_id")
        .and_then(Value::as_str)
        .unwrap_or_default()
        .to_string();
    let all_f64 = |node: &str| -> std::result::Result<(Vec<u64>, Vec<f64>), Failure> {
        let a = Array::open(store.clone(), node)?;
        Ok((a.shape().to_vec(), a.retrieve_array_subset::<Vec<f64>>(&a.subset_all())?))
    };
    let draw = Array::open(store.clone(), "/posterior/draw")?;
    let draws = draw.retrieve_array_subset::<Vec<i64>>(&draw.subset_all())?;
    let mut posterior = Vec::new();
    for node in Group::open(store.clone(), "/posterior")?.child_array_paths()? {
        let a = Array::open(store.clone(), node.as_str())?;
        if a.dimensionality() == 2 && a.data_type() == &data_type::float64() {
            let name = a
                .attributes()
                .get("long_name")
                .and_then(Value::as_str)
                .unwrap_or(node.as_str())
                .to_string();
            posterior.push((name, a.retrieve_array_subset::<Vec<f64>>(&a.subset_all())?));
        }
    }
    let (shape, log_likelihood) = all_f64("/log_likelihood/tau")?;
    let dim = |i: usize| shape.get(i).copied().unwrap_or(0) as usize;
    Ok(Stored {
        calibration_id,
        draws,
        posterior,
        log_likelihood,
        pointwise_shape: (dim(0), dim(1), dim(2)),
    })
}

impl DataGroup {
    fn new(name: &'static str, pairs: &[(&str, Value)]) -> DataGroup {
        DataGroup { name, attrs: attrs(pairs), nodes: Vec::new() }
    }

    fn put(
        &mut self,
        name: &str,
        dims: &[(&'static str, usize)],
        values: Values,
        pairs: &[(&str, Value)],
    ) {
        self.nodes.push(Node {
            name: name.to_string(),
            dims: dims.to_vec(),
            values,
            attrs: attrs(pairs),
        });
    }
}

/// The InferenceData of a calibration's `sample`, with the pointwise terms
/// `pw` of a thinned set of its draws.
pub fn inference_data(
    sample: &PosteriorSample,
    pw: PointwiseDraws,
    info: &StoreInfo,
) -> InferenceData {
    let chains = sample.chains.chains();
    let walkers = chains / info.ensembles.max(1);
    // the draws the diagnostics use
    let n = analysed_draws(sample.chains.steps().saturating_sub(info.burn_in));
    let first = sample.chains.steps() - n;
    let root = attrs(&[
        ("created_by", json!("mrbp")),
        ("mrbp_version", json!(env!("CARGO_PKG_VERSION"))),
        ("inference_library", json!("mrbp")),
        ("calibration_id", json!(info.calibration_id)),
        (
            "sampler",
            json!(format!(
                "affine-invariant ensemble: {} ensembles of {walkers} walkers",
                info.ensembles
            )),
        ),
        ("r_hat_note", json!(RHAT_NOTE)),
    ]);
    let mut groups = Vec::new();

    let draw_coord: Vec<i64> = (first..first + n).map(|s| s as i64).collect();
    let ensemble: Vec<i64> = (0..chains).map(|c| (c / walkers.max(1)) as i64).collect();
    let chain_coord: Vec<i64> = (0..chains as i64).collect();
    let stats_attrs = [
        ("burn_in", json!(info.burn_in)),
        ("first_draw", json!(first)),
        ("r_hat_note", json!(RHAT_NOTE)),
    ];
    // (step, chain) of every cell of a chain × draw array, chain-major
    let cells: Vec<(usize, usize)> =
        (0..chains).flat_map(|c| (first..first + n).map(move |s| (s, c))).collect();
    let by_draw = [("chain", chains), ("draw", n)];
    let on_ensemble = || [("coordinates", json!("ensemble"))];
    for name in ["posterior", "sample_stats"] {
        let mut g = DataGroup::new(name, &stats_attrs);
        g.put("chain", &[("chain", chains)], Values::I64(chain_coord.clone()), &[]);
        g.put("draw", &[("draw", n)], Values::I64(draw_coord.clone()), &[]);
        g.put("ensemble", &[("chain", chains)], Values::I64(ensemble.clone()), &[]);
        if name == "posterior" {
            for (i, coordinate) in sample.layout.names.iter().enumerate() {
                let values: Vec<f64> =
                    cells.iter().map(|&(s, c)| sample.chains.at(s, c, i)).collect();
                let pairs = [
                    ("units", json!(unit_of(coordinate))),
                    ("coordinates", json!("ensemble")),
                    ("long_name", json!(coordinate)),
                ];
                g.put(&node_name(coordinate), &by_draw, Values::F64(values), &pairs);
            }
        } else {
            let lp: Vec<f64> =
                cells.iter().map(|&(s, c)| sample.chains.log_prob[s * chains + c]).collect();
            g.put("lp", &by_draw, Values::F64(lp), &on_ensemble());
            let accepted: Vec<bool> =
                cells.iter().map(|&(s, c)| sample.chains.accepted[s * chains + c]).collect();
            g.put("accepted", &by_draw, Values::Bool(accepted), &on_ensemble());
        }
        groups.push(g);
    }

    // the observations, their coordinates in every group that has them
    let nobs = pw.observed.len();
    let obs: Vec<i64> = (0..nobs as i64).collect();
    let run_names: Vec<String> = pw.run.iter().map(|&j| pw.runs[j].clone()).collect();
    let pw_steps: Vec<i64> = pw.steps.iter().map(|&s| s as i64).collect();
    let thinning = [
        ("thinned_steps", json!(pw.steps)),
        ("stride_at_least", json!(info.stride)),
        ("draws", json!(pw.steps.len() * pw.chains)),
        ("note", json!("every chain at a few steps at least tau_max apart: nearly independent draws, so az.loo(idata, reff=1.0)")),
        ("factorisation", json!("terms are conditional densities p(y_k | earlier y of the run or branch, theta) that sum to the likelihood the sampler used")),
    ];
    let coords = json!("run time");
    let dims = [("chain", chains), ("draw", pw_steps.len()), ("obs", nobs)];
    let shear = [
        ("coordinates", coords.clone()),
        ("units", json!("Pa")),
        ("long_name", json!("shear stress")),
    ];
    // a group of the observations, with their coordinates (and the draws')
    let observations = |name: &'static str| {
        let mut g = DataGroup::new(name, if name == "observed_data" { &[] } else { &thinning });
        g.put("obs", &[("obs", nobs)], Values::I64(obs.clone()), &[]);
        g.put("run", &[("obs", nobs)], Values::Str(run_names.clone()), &[]);
        g.put("time", &[("obs", nobs)], Values::F64(pw.time.clone()), &[("units", json!("s"))]);
        if name != "observed_data" {
            g.put("chain", &[("chain", chains)], Values::I64(chain_coord.clone()), &[]);
            g.put("draw", &[("draw", pw_steps.len())], Values::I64(pw_steps.clone()), &[]);
        }
        g
    };
    let mut g = observations("log_likelihood");
    g.put(
        "tau",
        &dims,
        Values::F64(pw.log_likelihood),
        &[("coordinates", coords.clone()), ("units", json!("ln(1/Pa)"))],
    );
    groups.push(g);
    let mut g = observations("posterior_predictive");
    g.put("tau", &dims, Values::F32(pw.replicate), &shear);
    groups.push(g);
    let mut g = observations("observed_data");
    g.put("tau", &[("obs", nobs)], Values::F64(pw.observed), &shear);
    groups.push(g);
    InferenceData { attrs: root, groups }
}

fn build(dir: &Path, data: &InferenceData) -> std::result::Result<(), Failure> {
    let store: ReadableWritableListableStorage = Arc::new(FilesystemStore::new(dir)?);
    let mut root = GroupBuilder::new().build(store.clone(), "/")?;
    root.attributes_mut().extend(data.attrs.clone());
    root.store_metadata()?;
    for group in &data.groups {
        let mut g = GroupBuilder::new().build(store.clone(), &format!("/{}", group.name))?;
        g.attributes_mut().extend(group.attrs.clone());
        g.store_metadata()?;
        for node in &group.nodes {
            let path = format!("/{}/{}", group.name, node.name);
            match &node.values {
                Values::F64(v) => put(&store, &path, &node.dims, v, &node.attrs)?,
                Values::F32(v) => put(&store, &path, &node.dims, v, &node.attrs)?,
                Values::I64(v) => put(&store, &path, &node.dims, v, &node.attrs)?,
                Values::Bool(v) => put(&store, &path, &node.dims, v, &node.attrs)?,
                Values::Str(v) => put(&store, &path, &node.dims, v, &node.attrs)?,
            }
        }
    }
    Ok(())
}

/// The element types of the store: their Zarr data type and fill value
/// (which xarray reads as a storage detail of Zarr v3, not as a mask).
trait Element {
    fn data_type() -> DataType;
    fn fill() -> FillValueMetadata;
}

impl Element for f64 {
    fn data_type() -> DataType {
        data_type::float64()
    }
    fn fill() -> FillValueMetadata {
        FillValueMetadata::from(f64::NAN)
    }
}

impl Element for f32 {
    fn data_type() -> DataType {
        data_type::float32()
    }
    fn fill() -> FillValueMetadata {
        FillValueMetadata::from(f32::NAN)
    }
}

impl Element for i64 {
    fn data_type() -> DataType {
        data_type::int64()
    }
    fn fill() -> FillValueMetadata {
        FillValueMetadata::from(0i64)
    }
}

impl Element for bool {
    fn data_type() -> DataType {
        data_type::bool()
    }
    fn fill() -> FillValueMetadata {
        FillValueMetadata::from(false)
    }
}

impl Element for String {
    fn data_type() -> DataType {
        data_type::string()
    }
    fn fill() -> FillValueMetadata {
        FillValueMetadata::from("")
    }
}

fn attrs(pairs: &[(&str, Value)]) -> Map<String, Value> {
    pairs.iter().map(|(k, v)| (k.to_string(), v.clone())).collect()
}

/// One array over the named dimensions of the given lengths: a single
/// chunk, or one per chain for the pointwise (chain, draw, obs) arrays,
/// which keeps the encoding's copies small.
fn put<'a, T>(
    store: &ReadableWritableListableStorage,
    path: &str,
    dims: &[(&str, usize)],
    values: &'a [T],
    attributes: &Map<String, Value>,
) -> std::result::Result<(), Failure>
where
    &'a [T]: IntoArrayBytes<'a>,
    T: Element,
{
    let shape: Vec<u64> = dims.iter().map(|(_, n)| *n as u64).collect();
    if shape.iter().product::<u64>() != values.len() as u64 {
        return Err(format!("{path}: {} values for the shape {shape:?}", values.len()).into());
    }
    let fill = T::fill();
    let mut chunk: Vec<u64> = shape.iter().map(|s| (*s).max(1)).collect();
    if chunk.len() == 3 {
        chunk[0] = 1;
    }
    let array = ArrayBuilder::new(shape.clone(), chunk, T::data_type(), fill)
        .dimension_names(Some(dims.iter().map(|(d, _)| *d)))
        .attributes(attributes.clone())
        .build(store.clone(), path)?;
    array.store_metadata()?;
    if !values.is_empty() {
        array.store_array_subset(&array.subset_all(), values)?;
    }
    Ok(())
}

/// A Zarr node name for a coordinate's name (`/` separates nodes).
fn node_name(name: &str) -> String {
    name.replace('/', "_")
}
