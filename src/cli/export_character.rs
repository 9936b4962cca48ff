//! `rigless export-character hand|body DIR` (and `export-hand DIR`, a hidden alias of
//! `export-character hand DIR`): writes a procedural character as an OBJ mesh and a
//! complete character file, a starting point for a user's own and the file `calibrate
//! --write` stores a take's marker layout in.

use anyhow::{Context, Result};
use clap::ValueEnum;
use rigless::character::demo::{body_bind_params, demo_body, demo_hand, hand_bind_params};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct ExportCharacterArgs {
    /// Which procedural character: the hand (`hand.obj`, `hand.toml`) or the body
    /// (`body.obj`, `body.toml`).
    #[arg(value_enum)]
    character: Procedural,
    /// Folder to write the mesh and the character file into (created if missing).
    dir: PathBuf,
}

#[derive(clap::Args)]
pub struct ExportHandArgs {
    /// Folder to write `hand.obj` and `hand.toml` into (created if missing).
    dir: PathBuf,
}

#[derive(Clone, Copy, ValueEnum)]
enum Procedural {
    Hand,
    Body,
}

pub fn run(a: ExportCharacterArgs) -> Result<()> {
    let (character, bind) = match a.character {
        Procedural::Hand => (demo_hand(), hand_bind_params()),
        Procedural::Body => (demo_body(), body_bind_params()),
    };
    let path = rigless::character::file::write_character_files(&character, Some(&bind), &a.dir)
        .with_context(|| format!("writing the {} into {}", character.name, a.dir.display()))?;
    println!(
        "wrote {} and its mesh; try: rigless bake {}",
        path.display(),
        path.display()
    );
    Ok(())
}

/// `export-hand DIR`: `export-character hand DIR`.
pub fn run_hand(a: ExportHandArgs) -> Result<()> {
    run(ExportCharacterArgs {
        character: Procedural::Hand,
        dir: a.dir,
    })
}
