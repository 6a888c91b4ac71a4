//! `scalpel instruct ADDR --certs DIR --name NAME fault <kind> [params] | list | clear [ID]`:
//! an instructor's commands to a station over QUIC (docs/PROTOCOL.md, "Faults"). Each run
//! is one connection and one command; the answer is printed (JSON with `--json`), and a
//! refused command exits with an error that gives the server's reason.

use anyhow::{Context, bail};
use scalpel_client::remote::Instructor;
use scalpel_proto::wire::{Fault, FaultSpec, Outcome, ScheduledFault, Start};

use crate::remote_target::RemoteTarget;

/// Who instructs where.
pub struct InstructArgs<'a> {
    /// The server, and this instructor's certificate.
    pub target: &'a RemoteTarget,
    /// JSON output.
    pub json: bool,
}

/// A fault's parameters as the command line gives them; [`fault`] checks that the kind
/// has what it needs. Negative numbers parse (clap took `--newtons -5` for a flag and told
/// the user to write `-- -5`), so the range check can say what is allowed.
#[derive(Debug, Clone, Copy, Default, clap::Args)]
pub struct FaultParams {
    /// Added device latency (ms, 0–1000).
    #[arg(long, allow_negative_numbers = true)]
    pub ms: Option<f32>,
    /// Noise on the device position, standard deviation (mm, 0–20).
    #[arg(long, allow_negative_numbers = true)]
    pub sigma_mm: Option<f32>,
    /// Spike magnitude (N, 0–1000; the output stage still limits the force).
    #[arg(long, allow_negative_numbers = true)]
    pub newtons: Option<f32>,
    /// Force cap (N).
    #[arg(long, allow_negative_numbers = true)]
    pub max_n: Option<f32>,
    /// Stiffness factor (0.1–10) or slowdown factor (1–100).
    #[arg(long, allow_negative_numbers = true)]
    pub factor: Option<f32>,
    /// Stiffness ramp in and out (ms, default 200).
    #[arg(long, allow_negative_numbers = true)]
    pub ramp_ms: Option<u32>,
}

/// What to ask.
pub enum Request {
    /// Schedule a fault of `kind`.
    Fault {
        /// Its kind, as `Fault::kind` spells it.
        kind: String,
        /// Its parameters.
        params: FaultParams,
        /// Station tick to start at (none: now).
        at: Option<u64>,
        /// Duration (ms; 0: until cleared).
        duration_ms: u32,
    },
    /// List the faults.
    List,
    /// Clear one fault or all.
    Clear(Option<u64>),
}

/// The fault `kind` with `params`; an error names what is missing or not for this kind.
pub fn fault(kind: &str, p: &FaultParams) -> anyhow::Result<Fault> {
    let need = |v: Option<f32>, flag: &str| v.with_context(|| format!("{kind} needs --{flag}"));
    let fault = match kind {
        "device-dropout" => Fault::DeviceDropout,
        "device-latency" => Fault::DeviceLatency {
            ms: need(p.ms, "ms")?,
        },
        "pose-noise" => Fault::PoseNoise {
            sigma_mm: need(p.sigma_mm, "sigma-mm")?,
        },
        "force-spike" => Fault::ForceSpike {
            newtons: need(p.newtons, "newtons")?,
        },
        "force-saturation" => Fault::ForceSaturation {
            max_n: need(p.max_n, "max-n")?,
        },
        "tissue-stiffness" => Fault::TissueStiffness {
            factor: need(p.factor, "factor")?,
            ramp_ms: p.ramp_ms.unwrap_or(200),
        },
        "sim-stall" => Fault::SimStall,
        "sim-slowdown" => Fault::SimSlowdown {
            factor: need(p.factor, "factor")?,
        },
        "renderer-freeze" => Fault::RendererFreeze,
        "observer-stream-loss" => Fault::ObserverStreamLoss,
        other => bail!(
            "{other}: not a fault; the kinds are {}",
            Fault::EXAMPLES.map(|f| f.kind()).join(", ")
        ),
    };
    // Parameters this kind does not take are a mistake worth saying.
    let given = [
        ("ms", p.ms.is_some()),
        ("sigma-mm", p.sigma_mm.is_some()),
        ("newtons", p.newtons.is_some()),
        ("max-n", p.max_n.is_some()),
        ("factor", p.factor.is_some()),
        ("ramp-ms", p.ramp_ms.is_some()),
    ];
    let takes: &[&str] = match fault {
        Fault::DeviceLatency { .. } => &["ms"],
        Fault::PoseNoise { .. } => &["sigma-mm"],
        Fault::ForceSpike { .. } => &["newtons"],
        Fault::ForceSaturation { .. } => &["max-n"],
        Fault::TissueStiffness { .. } => &["factor", "ramp-ms"],
        Fault::SimSlowdown { .. } => &["factor"],
        _ => &[],
    };
    if let Some((flag, _)) = given.iter().find(|(f, g)| *g && !takes.contains(f)) {
        bail!("{kind} does not take --{flag}");
    }
    fault.check().map_err(anyhow::Error::msg)?;
    Ok(fault)
}

/// Runs one command.
pub fn run(args: &InstructArgs<'_>, request: Request) -> anyhow::Result<()> {
    // Checked before connecting: a typo costs no connection.
    let spec = match &request {
        Request::Fault {
            kind,
            params,
            at,
            duration_ms,
        } => Some(FaultSpec {
            fault: fault(kind, params)?,
            start: at.map_or(Start::Now, Start::AtTick),
            duration_ms: *duration_ms,
        }),
        _ => None,
    };
    let t = args.target;
    let addr = t.socket_addr()?;
    RemoteTarget::runtime()?.block_on(async {
        let mut instructor = Instructor::connect(addr, &t.server_name, &t.credentials(), &t.name)
            .await
            .with_context(|| format!("cannot instruct {}", t.addr))?;
        let (outcome, faults) = match (&request, spec) {
            (_, Some(spec)) => (instructor.schedule(spec).await?, None),
            (Request::List, _) => {
                let (o, f) = instructor.list().await?;
                (o, Some(f))
            }
            (Request::Clear(id), _) => (instructor.clear(*id).await?, None),
            (Request::Fault { .. }, None) => unreachable!("a fault request has its spec"),
        };
        instructor.0.close_and_wait().await;
        print(args.json, &outcome, faults.as_deref())
    })
}

fn print(json: bool, outcome: &Outcome, faults: Option<&[ScheduledFault]>) -> anyhow::Result<()> {
    if json {
        println!(
            "{}",
            serde_json::json!({ "outcome": outcome, "faults": faults })
        );
    } else {
        match outcome {
            Outcome::Scheduled { id } => println!("scheduled: fault {id}"),
            Outcome::Cleared { count } => println!("cleared {count} fault(s)"),
            Outcome::Listed => {
                let faults = faults.unwrap_or_default();
                if faults.is_empty() {
                    println!("no faults");
                }
                for f in faults {
                    println!(
                        "fault {}  {:<20} {:?}  start {:?}  {}  by {}  {}",
                        f.id,
                        f.spec.fault.kind(),
                        f.spec.fault,
                        f.spec.start,
                        if f.spec.duration_ms == 0 {
                            "until cleared".to_string()
                        } else {
                            format!("{} ms", f.spec.duration_ms)
                        },
                        f.by,
                        if f.active { "ACTIVE" } else { "scheduled" }
                    );
                }
            }
            Outcome::Rejected { .. } => {}
        }
    }
    if let Outcome::Rejected { reason } = outcome {
        bail!("refused: {reason}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_kind_parses_and_wrong_parameters_are_named() {
        for example in Fault::EXAMPLES {
            let p = FaultParams {
                ms: matches!(example, Fault::DeviceLatency { .. }).then_some(50.0),
                sigma_mm: matches!(example, Fault::PoseNoise { .. }).then_some(1.0),
                newtons: matches!(example, Fault::ForceSpike { .. }).then_some(10.0),
                max_n: matches!(example, Fault::ForceSaturation { .. }).then_some(1.0),
                factor: match example {
                    Fault::TissueStiffness { .. } => Some(2.0),
                    Fault::SimSlowdown { .. } => Some(4.0),
                    _ => None,
                },
                ramp_ms: None,
            };
            assert_eq!(fault(example.kind(), &p).unwrap(), example);
        }
        let e = fault("device-latency", &FaultParams::default()).unwrap_err();
        assert!(e.to_string().contains("needs --ms"), "{e}");
        let p = FaultParams {
            newtons: Some(3.0),
            ..FaultParams::default()
        };
        let e = fault("sim-stall", &p).unwrap_err();
        assert!(e.to_string().contains("does not take --newtons"), "{e}");
        let p = FaultParams {
            factor: Some(500.0),
            ..FaultParams::default()
        };
        let e = fault("sim-slowdown", &p).unwrap_err();
        assert!(e.to_string().contains("factor 500"), "{e}");
        let e = fault("gremlins", &p).unwrap_err();
        assert!(e.to_string().contains("device-dropout"), "{e}");
    }
}
