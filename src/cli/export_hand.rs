//! `rigless export-hand DIR`: writes the procedural hand as an OBJ mesh and a complete
//! character file, a starting point for a user's own.

use anyhow::{Context, Result};
use rigless::character::demo::{demo_hand, hand_bind_params};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ExportHandArgs {
    /// Folder to write `hand.obj` and `hand.toml` into (created if missing).
    dir: PathBuf,
}

pub fn run(a: ExportHandArgs) -> Result<()> {
    let path = rigless::character::file::write_character_files(
        &demo_hand(),
        Some(&hand_bind_params()),
        &a.dir,
    )
    .with_context(|| format!("writing the hand into {}", a.dir.display()))?;
    println!(
        "wrote {} and its mesh; try: rigless bake {}",
        path.display(),
        path.display()
    );
    Ok(())
}
