//! placeholder
use crate::{Campaign, StageResult};
/// Pictures.
#[derive(Debug, Clone, Default)]
pub struct ReportPictures {}
/// json
pub fn report_json(_c: &Campaign, _r: &[StageResult]) -> serde_json::Value {
    serde_json::Value::Null
}
/// html
pub fn report_html(_c: &Campaign, _r: &[StageResult], _p: &ReportPictures) -> String {
    String::new()
}
