//! The one integration-test binary. Each module covers one concern.

// Shared helpers: synthetic DEMs, the shared-data path, running the CLI.
mod util;

// lat/lon ↔ face/(u,v) ↔ direction round trips over poles, edges and corners.
mod projection;
// Adjacent tiles and all 12 face edges agree where they overlap.
mod seams;
// The tiling stage: coverage, resume, determinism across thread counts, albedo.
mod tiling;
// The CLI contract: commands, JSON, exit code 2 and no partial output on bad input.
mod cli;
// DEM readers: good, damaged and truncated files, and the real DEMs in ../shared/data.
mod readers;
// Real DEMs tiled and queried at landmarks (skipped without ../shared/data).
mod realdata;
// The audit's nonsense DEMs (relief beyond the body, contradictory labels): exit 2 by key, or
// tiled only with --allow-relief (skipped without ../shared/data).
mod relief;
// Hundreds of damaged crops of the real DEMs through `penumbra tile`: exit 0 or 2, old tileset kept.
mod corpus;
// The EXR codec against independent readers (OpenEXR's Python bindings, the exr crate).
mod codec;
// Max and min/max mipmaps: bounds of the interpolated surface, reference twin, CLI.
mod mip;
// Horizon maps: fast sweep against brute force, analytic terrains, stiff cases, the CLI.
mod horizon;

// Several DEMs mosaicked per pixel with a feathered seam (LDEM_4 under Shoemaker), wanted tile
// sets, sources of different bodies refused.
mod mosaic;

// `penumbra export` to Cloud-Optimized GeoTIFF and DEMs read through GDAL (`--features gdal`;
// without it, the exit-2 message).
mod export;

// tileset.json consistency: every field the docs call validated, refused by name (a table).
mod manifest;

// The tileset store and stage runner: one writer, kill -9 and resume, stale products, damaged
// manifests.
mod store;

// Horizon stiff and extreme cases: spikes, cones, cliffs, corner, pole, voids, seam, threads.
mod horizon_cases;

// Fourier pyramids: streamed and from raw maps, reconstruction, sun visibility, bad input.
mod fourier;

// Shadow methods through the CLI: every method against the reference, tiles and boxes, bad input.
mod shadows;
// The shadow ray-marching methods in stiff cases with known answers (the library's API).
mod shadow_methods;

// The layering of docs/architecture.md on the source: no import circle between files, product
// files read and written only by the formats layer and the store.
mod architecture;

// The stage graph: shards in separate processes give one run's bytes; a toy stage defined in
// the test alone runs through the graph and the store.
mod graph;

// Damaged tilesets, generated: every product file swapped, replaced by a FIFO, linked to
// /dev/zero or sparse-padded is refused by its readers (exit 2, named, fast, small) and flagged
// by `penumbra verify`; non-file manifests; format-1 tilesets.
mod integrity;

// Tiles a scene's sun never needs: the per-tile horizon bound holds every computed horizon
// (analytic terrains, real DEMs), a pruned run renders the full run's lit fractions by every
// CPU shadow method, damaged lists of pruned tiles are refused.
mod prune;

// Scene files, `plan` and `bake SCENE`: bad scenes refused by line and key with nothing
// written; the plan's counts against what the bake writes.
mod scenes;

// A scene's stages as concurrent shard processes and a finish: the bytes of one bake for 1, 2,
// 4 and 7 shards; a killed shard rerun; a finish refused (exit 2, the shard named, nothing
// committed) with a shard missing or a staged file damaged; two finishes at once.
mod shards;
// `penumbra package`: the Celestia addon with the tileset as its cube-face products, its
// README and deterministic archive; bad input exits 2 and writes nothing.
mod package;
// `plan --slurm`: the scripts, bad flags (exit 2, nothing written), and a single-node Slurm
// cluster (skipped without Slurm, failed under CI) running the chain to one bake's bytes, a
// requeued array task resuming its shard.
mod slurm;

// `penumbra report`: every method against the reference on a tileset, the recommendation on a
// second sample, bad input, and report.html in a headless browser.
mod report;
// The stress catalogue (docs/stress.md): every stiff and extreme case as its own test, the
// weakened kernels failing them, and `penumbra stress` (exit 0, 1, 2).
mod stress;
