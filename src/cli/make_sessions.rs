//! `rigless make-sessions DIR`: writes the bundled sessions as C3D files.

use anyhow::{Context, Result};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct MakeSessionsArgs {
    /// Folder to write `NAME.c3d` into (created if missing).
    dir: PathBuf,
}

pub fn run(a: MakeSessionsArgs) -> Result<()> {
    std::fs::create_dir_all(&a.dir).with_context(|| format!("creating {}", a.dir.display()))?;
    for spec in &rigless::replay::bundled::SPECS {
        let bytes = rigless::replay::bundled::generate(spec)?;
        let path = a.dir.join(format!("{}.c3d", spec.name));
        std::fs::write(&path, &bytes).with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {} ({} bytes)", path.display(), bytes.len());
    }
    Ok(())
}
