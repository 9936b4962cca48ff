//! Recorded sessions from files: the Qualisys TSV reader (more formats come with the
//! replay issue).

pub mod tsv;
