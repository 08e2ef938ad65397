//! Prints the opening prior's decision for every object of one or more sequences, beside the kind
//! and orientation the sequence's `sequence.json` gives (when it has one), so that the prior can be
//! checked on new scenes without training.
//!
//! `cargo run --release -p trand-pipeline --example vessel_tops -- SEQ...`

use trand_pipeline::openings::{Profile, Top, support_under};
use trand_pipeline::reconstruct::{
    ReconstructOptions, find_openings, openings_box, openings_hull, train_views,
};

fn kinds(root: &std::path::Path) -> Vec<(u64, String)> {
    let Ok(text) = std::fs::read_to_string(root.join("sequence.json")) else {
        return Vec::new();
    };
    let Ok(json) = serde_json::from_str::<serde_json::Value>(&text) else {
        return Vec::new();
    };
    let objects = json["objects"].as_array().cloned().unwrap_or_default();
    objects
        .iter()
        .map(|o| {
            let mode = o["initial_mode"]
                .as_str()
                .or(o["params_m"]["initial_mode"].as_str())
                .unwrap_or("?");
            let kind = o["kind"].as_str().unwrap_or("?");
            (o["id"].as_u64().unwrap_or(0), format!("{kind} ({mode})"))
        })
        .collect()
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let opts = ReconstructOptions::default();
    for arg in std::env::args().skip(1) {
        let seq = trand_io::read_sequence(&arg)?;
        let views = train_views(&seq, &opts)?.views;
        let (openings, tops) = find_openings(&views, &opts)?;
        for o in &openings {
            let c = &o.carving;
            let top = c.centre(c.radius.len() - 1);
            let r: Vec<String> = c.radius.iter().map(|r| format!("{:.0}", r * 1e3)).collect();
            println!(
                "{arg} opening rim z {:.3} floor z {:.3} r {:.3}, carving centred at ({:.1}, {:.1}) mm at the rim, R(mm) {}",
                o.rim_z,
                o.floor_z,
                o.rim_radius,
                top.x * 1e3,
                top.y * 1e3,
                r.join(" ")
            );
        }
        let kinds = kinds(&seq.root);
        let b = openings_box(&views)?;
        let (hull, baseline) = openings_hull(&views, &opts, &b)?;
        for t in tops {
            let kind = kinds
                .iter()
                .find(|(id, _)| *id == t.object_id as u64)
                .map_or("?", |(_, k)| k.as_str());
            let decision = match t.top {
                Top::Open {
                    shape,
                    rim_z,
                    rim_radius,
                } => format!("OPEN {shape:?} rim z {rim_z:.3} r {rim_radius:.3}"),
                Top::Closed { because } => format!("closed {because:?}"),
            };
            let shape = hull.get(&t.object_id).and_then(|v| Profile::standing_on(v, baseline, support_under(t.object_id, v, &hull))).map_or(
                String::new(),
                |p| {
                    let r = &p.radius;
                    let widest = r.iter().fold(0.0f64, |a, &b| a.max(b));
                    format!(
                        "| z0 {:.3} h {:.3} top {:.3} widest {:.3} lean {:.2} elong {:.2} crown {:.2} crown-no-apex {:.2} box-top {:.3}",
                        p.z0,
                        r.len() as f64 * 0.002,
                        r[r.len() - 1],
                        widest,
                        p.lean,
                        p.elongation,
                        p.crown(),
                        {
                            let first = r.iter().position(|&v| v >= widest - 0.003).unwrap_or(0);
                            let top = r.iter().rposition(|&v| v > 0.004).unwrap_or(0) + 1;
                            (top - first) as f64 * 0.002 / widest
                        },
                        b.max[2]
                    )
                },
            );
            let support = hull
                .get(&t.object_id)
                .and_then(|v| support_under(t.object_id, v, &hull))
                .map_or(String::new(), |z| format!(" | on a support up to z {z:.3}"));
            println!(
                "{arg} {:>2} {kind:<22} {decision} {shape}{support}",
                t.object_id
            );
            if std::env::var_os("PROFILE").is_some()
                && let Some(p) = hull.get(&t.object_id).and_then(|v| {
                    Profile::standing_on(v, baseline, support_under(t.object_id, v, &hull))
                })
            {
                let r: Vec<String> = p
                    .radius
                    .iter()
                    .map(|r| format!("{:.0}", r * 1000.0))
                    .collect();
                println!(
                    "    axis ({:.1}, {:.1}) mm, R(mm) from z0: {}",
                    p.axis[0] * 1e3,
                    p.axis[1] * 1e3,
                    r.join(" ")
                );
            }
        }
    }
    Ok(())
}
