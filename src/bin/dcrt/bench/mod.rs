//! `dcrt bench`: the measurements behind the README's figures.

pub mod shading;
