//! The report as Markdown.

use super::StepReport;

/// The report's summary, the step's stages and the field's work, as Markdown tables.
pub fn table(r: &StepReport) -> String {
    let p = &r.peaks;
    let mut s = format!(
        "{}: {} timed steps after {} warm-up, {:.0} rays and {:.0} samples a step \
         ({:.1} a ray): {:.1} ms a step, {:.2} steps/s, {:.0} samples/s.\n\n\
         This machine, {} threads: matrix product {:.1} GFLOP/s, random 8-byte rows of a \
         {:.1} MiB table {:.2} GB/s, streamed read {:.1} GB/s. Field work ran on {:.2} \
         threads at once.\n\n\
         | the step (wall) | ms a step | share |\n|---|---|---|\n",
        r.source,
        r.steps,
        r.warmup,
        r.rays_per_step,
        r.samples_per_step,
        r.samples_per_ray,
        r.step_ms,
        r.steps_per_s,
        r.samples_per_s,
        p.threads,
        p.matmul_gflops,
        p.gather_table_mib,
        p.gather_gbs,
        p.stream_gbs,
        r.field_threads,
    );
    for row in &r.wall {
        s += &format!(
            "| {} | {:.2} | {:.1}% |\n",
            row.stage,
            row.ms_per_step,
            100.0 * row.share
        );
    }
    s += "\n| field work (thread seconds) | ms a step | share | calls a step | FLOP a sample \
          | bytes a sample (gathered) | GFLOP/s | GB/s | ideal ms | efficiency | bound |\n\
          |---|---|---|---|---|---|---|---|---|---|---|\n";
    for row in &r.work {
        let counted = row.flops_per_sample > 0.0 || row.bytes_per_sample > 0.0;
        let dash = |v: String| if counted { v } else { "-".into() };
        s += &format!(
            "| {} | {:.2} | {:.1}% | {:.1} | {} | {} | {} | {} | {} | {} | {} |\n",
            row.stage,
            row.thread_ms_per_step,
            100.0 * row.share,
            row.calls_per_step,
            dash(format!("{:.0}", row.flops_per_sample)),
            dash(format!(
                "{:.0} ({:.0})",
                row.bytes_per_sample, row.gathered_per_sample
            )),
            dash(format!("{:.2}", row.gflops)),
            dash(format!("{:.2}", row.gbs)),
            dash(format!("{:.2}", row.ideal_ms_per_step)),
            dash(format!("{:.0}%", 100.0 * row.efficiency)),
            row.bound,
        );
    }
    s += &format!(
        "\nThe counted kernels at this machine's ceilings: {:.2} ms of the step's {:.1} ms \
         ({:.1}%).\n",
        r.counted_ideal_ms,
        r.step_ms,
        100.0 * r.counted_ideal_ms / r.step_ms.max(1e-12)
    );
    s
}
