//! A package `penumbra package` wrote opens as the tileset it was made from: `penumbra-view`
//! finds the cube-face tileset inside the addon folder and draws the same frame, byte for byte.

use std::path::Path;

use penumbra::package::bundle::{package, PackageOptions};
use penumbra::package::celestia::AddonOptions;
use penumbra::progress::NoProgress;

use crate::util::{albedo_globe, gpu, json, run, tmp};

/// Render `dir` headless into `png` (the globe from above 0°, 0° with the sun behind the eye);
/// the report and the frame's bytes.
fn frame(dir: &Path, png: &Path) -> (serde_json::Value, Vec<u8>) {
    let v = json(&run(&[
        dir.to_str().unwrap(),
        "--headless",
        "--out",
        png.to_str().unwrap(),
        "--size",
        "160x120",
        "--frames",
        "1",
        "--sun-lat",
        "0",
        "--sun-lon",
        "0",
        "--method",
        "extrema",
        "--json",
    ]));
    (v, std::fs::read(png).unwrap())
}

#[test]
fn a_package_renders_as_the_tileset_it_was_made_from() {
    if !gpu() {
        return;
    }
    let d = tmp();
    let pkg = d.path().join("penumbra-moon");
    let opts = PackageOptions {
        addon: AddonOptions {
            vt_tile_size: 64,
            ..AddonOptions::default()
        },
        ..PackageOptions::default()
    };
    package(albedo_globe(), &pkg, &opts, &NoProgress).unwrap();
    let (a, from_tileset) = frame(albedo_globe(), &d.path().join("tileset.png"));
    let (b, from_package) = frame(&pkg, &d.path().join("package.png"));
    // A frame with the globe in it, not an empty one that two failures would share.
    let surface = |v: &serde_json::Value| v["pixels"]["surface"].as_u64().unwrap();
    assert!(surface(&a) > 5000, "{a}");
    assert_eq!(surface(&a), surface(&b), "{a}\n{b}");
    assert_eq!(a["tiles"], b["tiles"], "the same tiles drawn");
    assert!(
        from_tileset == from_package,
        "the package's frame differs from its tileset's"
    );
}
