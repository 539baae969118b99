//! PNG plots of a run (being written; see issue #4).
// TEMPORARY until the plots module lands.
#[allow(missing_docs)]
#[derive(Debug, thiserror::Error)]
#[error("plots are not written yet")]
pub struct PlotError;
#[allow(missing_docs)]
pub fn write_plots(
    _dir: &std::path::Path,
    _scene: &ecp_formulations::stepper::Scene,
    _records: &[ecp_formulations::stepper::StepRecord],
) -> Result<Vec<std::path::PathBuf>, PlotError> {
    Err(PlotError)
}
