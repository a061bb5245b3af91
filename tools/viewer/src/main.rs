//! `penumbra-view`: see the crate documentation of `penumbra_view`.

fn main() {
    eprintln!("penumbra-view: not built yet (issue 12)");
    std::process::exit(2);
}
