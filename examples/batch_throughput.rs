//! Throughput of batch runs (`ecp::batch`) on the desk (`scenes/desk.toml`, 400 steps per run):
//! desk steps per second on 1 and 2 threads, the scaling between them, whether the results are
//! the same bytes, and the time of one 400-step run (the Rust side of the Python package's
//! overhead, `docs/python.md#measurements`).
//!
//! `cargo run --release --example batch_throughput [-- --runs 16 --repeats 5]`
//!
//! Each figure is the best of `--repeats` repetitions (the machine may be shared); the load
//! average at the start is printed beside them.

use std::time::Instant;

use ecp::batch::{Batch, BatchOptions, linspace, result_bytes};
use ecp::formulations::sensitivity::Param;

fn arg(name: &str, default: usize) -> usize {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// CPU time of this process so far, all threads (s), from `/proc/self/stat` (Linux; NaN
/// elsewhere): with the machine shared, the wall-clock scaling shows how many cores the batch
/// got, the CPU time whether its threads did more work in all than one thread alone.
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // Fields after the command name (which ends with ')'): utime and stime are the 12th and
    // 13th, in clock ticks of 1/100 s.
    let rest = stat.rsplit(')').next().unwrap_or("");
    let fields: Vec<&str> = rest.split_whitespace().collect();
    match (fields.get(11), fields.get(12)) {
        (Some(u), Some(s)) => match (u.parse::<f64>(), s.parse::<f64>()) {
            (Ok(u), Ok(s)) => (u + s) / 100.0,
            _ => f64::NAN,
        },
        _ => f64::NAN,
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let runs = arg("--runs", 16);
    let repeats = arg("--repeats", 5).max(1);
    let file = ecp::scene::load_scene("scenes/desk.toml".as_ref())?;
    let steps = file.scene.num_steps();
    let points = linspace(0.20, 0.24, runs)
        .into_iter()
        .map(|mu| vec![(Param::Mu, mu)])
        .collect();
    let batch = Batch::points(&file, points)?;
    let load = std::fs::read_to_string("/proc/loadavg").unwrap_or_default();
    println!(
        "desk, {runs} runs × {steps} steps, best of {repeats}; load average {}",
        load.split_whitespace()
            .take(3)
            .collect::<Vec<_>>()
            .join(" ")
    );

    let mut rates = Vec::new();
    let mut cpu = Vec::new();
    let mut bytes = Vec::new();
    for threads in [1, 2] {
        let options = BatchOptions {
            threads: Some(threads),
            ..BatchOptions::default()
        };
        let mut best = f64::INFINITY;
        let cpu_started = cpu_seconds();
        for _ in 0..repeats {
            let started = Instant::now();
            let results = batch.run(&options)?;
            best = best.min(started.elapsed().as_secs_f64());
            if results.iter().any(|r| r.error.is_some()) {
                return Err("a desk run failed".into());
            }
            bytes.push(result_bytes(&results));
        }
        let cpu_per_batch = (cpu_seconds() - cpu_started) / repeats as f64;
        let rate = (runs * steps) as f64 / best;
        println!(
            "threads {threads}: {best:.3} s, {rate:.0} desk steps/s ({:.1} µs per step); CPU \
             time {cpu_per_batch:.3} s per batch",
            1e6 / rate
        );
        rates.push(rate);
        cpu.push(cpu_per_batch);
    }
    println!("scaling 2 threads / 1 thread: {:.2}×", rates[1] / rates[0]);
    println!(
        "CPU time 2 threads / 1 thread: {:.3} (1: no extra work, the scaling is the cores the \
         batch got)",
        cpu[1] / cpu[0]
    );
    println!(
        "results bitwise identical across thread counts and repetitions: {}",
        bytes.windows(2).all(|w| w[0] == w[1])
    );

    // One run as the Python package's `Simulation(scene).run()` does it: set-up, 400 steps with
    // the default fallbacks, every record kept.
    let single = Batch::scenes([file.clone()]);
    let options = BatchOptions {
        threads: Some(1),
        records: true,
        ..BatchOptions::default()
    };
    let mut best = f64::INFINITY;
    for _ in 0..repeats.max(5) {
        let started = Instant::now();
        let r = single.run(&options)?;
        best = best.min(started.elapsed().as_secs_f64());
        assert_eq!(r[0].records.len(), steps);
    }
    println!(
        "one {steps}-step run with records (the Rust side of the Python overhead): {:.2} ms",
        best * 1e3
    );
    Ok(())
}
