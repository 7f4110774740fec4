//! The inference server. Filled in by the infer-server issue.
