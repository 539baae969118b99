//! Writes the pivoting benchmark's LCP instances as the JSON that `ecp lcp` reads:
//! `lcp_n10.json`, `lcp_n30.json`, `lcp_n100.json`, `lcp_n300.json` (dense symmetric positive
//! definite `M`, [`ecp::lcp::random_lcp`] with seed 1, the instances of `benches/lemke.rs`).
//!
//! ```text
//! cargo run --release --example lcp_instances -- target/lcp
//! cargo run --release -- lcp target/lcp/lcp_n100.json --repeat 200
//! /usr/bin/python3 benches/siconos_lemke.py target/lcp/lcp_n100.json --repeat 200
//! ```

use std::path::PathBuf;

/// The sizes of the benchmark.
const SIZES: [usize; 4] = [10, 30, 100, 300];

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let dir = std::env::args()
        .nth(1)
        .map_or_else(|| PathBuf::from("target/lcp"), PathBuf::from);
    std::fs::create_dir_all(&dir)?;
    for n in SIZES {
        let path = dir.join(format!("lcp_n{n}.json"));
        std::fs::write(&path, ecp::lcp::random_lcp(n, 1).to_json())?;
        println!("{}", path.display());
    }
    Ok(())
}
