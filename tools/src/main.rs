//! `scalpel`: the command line of the scalpel surgical cutting simulator.
//!
//! Scenes (list, inspect, export), the demo, and benchmarks. Every report has a `--json`
//! form for scripts; errors go to stderr with a non-zero exit status.

mod archive;
mod bench;
mod certs_cmd;
mod cut_cmd;
mod cutrun;
mod export;
mod instruct_cmd;
mod lab_cmd;
mod lesson_cmd;
mod lesson_report;
mod load;
mod mock_cmd;
mod observe_cmd;
mod observe_tui;
mod plot;
mod probe_cmd;
mod progress;
mod remote_target;
mod replay_cmd;
mod report;
mod settle_cmd;
mod stats;
mod validate_cmd;
mod view_cmd;
mod wound_watch;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use scalpel_sim::geometry::LengthUnit;

#[derive(Parser)]
#[command(
    name = "scalpel",
    version,
    about = "Real-time haptic soft-tissue cutting: scenes, reports and benchmarks"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build the default scene (the liver of the paper's Table 1) and print its report.
    Demo {
        /// Built-in scene to use instead of the liver.
        #[arg(long, default_value = "liver")]
        scene: String,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Built-in scenes, scene files and meshes.
    #[command(subcommand)]
    Scene(SceneCommand),
    /// Run the analytic validation benchmarks (physics.md §8); exit status 1 if any fails.
    Validate {
        /// Print JSON: a list of {name, error, tolerance, pass, wall_ms, ...}.
        #[arg(long)]
        json: bool,
        /// Run only these benchmarks (comma-separated ids, e.g. B1,B9).
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
    },
    /// Run a scripted blade trajectory on a cutting scene and write the force curve
    /// (force.csv, force.png), the cut surface (incision.vtk), a render of the incision
    /// (incision.png) and the figures (metrics.json).
    Cut {
        #[command(flatten)]
        target: TargetArgs,
        /// Blade script (TOML keyframes, see docs/CUTTING.md); default: a 60 mm stroke at
        /// 5 mm/s, 10 mm deep, along the organ's long axis.
        #[arg(long, conflicts_with = "strokes")]
        script: Option<PathBuf>,
        /// Instead of one stroke, a lab session of this many strokes one after the other at
        /// places and headings drawn from `--seed` (docs/CUTTING.md, "A session").
        #[arg(long)]
        strokes: Option<usize>,
        /// Seed of a session's strokes.
        #[arg(long, default_value_t = 1, requires = "strokes")]
        seed: u64,
        /// Output folder (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Format of the cut surface mesh.
        #[arg(long, default_value = "vtk", value_parser = ["vtk", "ply", "obj"])]
        mesh_format: String,
        /// Threads for the simulation, as a station's `realtime.sim_threads` (1 or 2; the
        /// same results either way).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
        threads: u32,
        /// Print the metrics as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Let a supported organ come to rest under gravity (the scene's, or standard gravity
    /// when it has none) and report its sag; writes the settled surface (settled.vtk) and a
    /// render of it on its supports (settled.png).
    Settle {
        #[command(flatten)]
        target: TargetArgs,
        /// Output folder (created if missing).
        #[arg(long, default_value = "settled")]
        out: PathBuf,
        /// Print {sag_mm, max_displacement_mm, settle_s, residual_n, ...} as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Press a flat cylindrical punch (or the scene's blade) quasi-statically into the
    /// supported organ (from where it rests under the scene's gravity, or standard gravity
    /// when it has none) and report the force the tissue puts back, its stiffness and the
    /// half-space value 2aE/(1−ν²).
    Probe {
        #[command(flatten)]
        target: TargetArgs,
        #[command(flatten)]
        args: probe_cmd::ProbeArgs,
    },
    /// Whole-system benchmarks.
    #[command(subcommand)]
    Bench(BenchCommand),
    /// A lab's certificates for the QUIC endpoint (mutual TLS; the role is in the client
    /// certificate).
    #[command(subcommand)]
    Certs(CertsCommand),
    /// Observe a station remotely over QUIC: figures once a second, events, frames.
    Observe {
        #[command(flatten)]
        target: remote_target::RemoteTarget,
        /// Ask for frames (30 per second) too.
        #[arg(long)]
        frames: bool,
        /// Stop after this many seconds.
        #[arg(long)]
        seconds: Option<f64>,
        /// One JSON object per update.
        #[arg(long)]
        json: bool,
        /// Lines of text instead of the live view (the default when the output is not a
        /// terminal).
        #[arg(long)]
        plain: bool,
    },
    /// Instruct a station over QUIC (an instructor certificate): schedule a fault, list
    /// the faults, clear them (docs/PROTOCOL.md, "Faults").
    Instruct {
        #[command(flatten)]
        target: remote_target::RemoteTarget,
        /// The answer as JSON.
        #[arg(long)]
        json: bool,
        #[command(subcommand)]
        what: InstructCommand,
    },
    /// The mock haptic device: plays a blade script to a station over shared memory at a
    /// true 1 kHz and records the forces it receives (docs/PROTOCOL.md).
    MockDevice {
        /// Station name (the server's `station`).
        #[arg(long)]
        station: String,
        /// Keyframe script, TOML or CSV (docs/CUTTING.md); default: the scene's demo cut.
        #[arg(long)]
        script: Option<PathBuf>,
        /// Scene whose demo cut to play when there is no script.
        #[arg(long, default_value = "liver")]
        scene: String,
        /// Record the forces received, one CSV row per tick.
        #[arg(long)]
        out: Option<PathBuf>,
        /// Stop after this many seconds (default: when the script ends).
        #[arg(long)]
        duration: Option<f64>,
        /// Play the script again and again.
        #[arg(long = "loop")]
        looping: bool,
        /// Samples per second.
        #[arg(long, default_value_t = 1000.0)]
        rate_hz: f64,
        /// Print the summary as JSON.
        #[arg(long)]
        json: bool,
    },
    /// Draw a station's live surface from its shared-memory render frames, in a window
    /// (arrow keys turn, +/- zoom, Esc quits) or headless into a PNG.
    View {
        /// Station name (the server's `station`).
        #[arg(long)]
        station: String,
        /// Render headless to this PNG and exit (default: a live window).
        #[arg(long)]
        snapshot: Option<PathBuf>,
        /// Frames to receive before the snapshot.
        #[arg(long, default_value_t = 1)]
        after: u64,
        /// Give up after this many seconds without enough frames.
        #[arg(long, default_value_t = 30.0)]
        timeout: f64,
        /// Window mode: close after drawing this many frames.
        #[arg(long)]
        exit_after: Option<u64>,
    },
    /// Lessons: planned incisions, no-go structures, force limits and pass criteria
    /// (docs/LESSONS.md), and scripted trainees that perform them.
    #[command(subcommand)]
    Lesson(LessonCommand),
    /// Score a station's session on its lesson: replays the journal and writes report.html
    /// (the plan against the cut, the depth profile, the force with its limits, the metrics,
    /// pass or fail) and report.json. With --lab DIR instead: archives the lab's new
    /// journals (every *.journal under DIR) and writes the learning curves per trainee
    /// (lab.html, lab.csv, lab.json).
    Report {
        /// The session's journal (`scalpel-server --journal FILE`).
        #[arg(required_unless_present = "lab", conflicts_with = "lab")]
        journal: Option<PathBuf>,
        /// The lesson (built-in or file); default: the one the station ran and journaled.
        #[arg(long, conflicts_with = "lab")]
        lesson: Option<String>,
        /// Summarise the lab whose journals are under this folder.
        #[arg(long, value_name = "DIR")]
        lab: Option<PathBuf>,
        /// With --lab: the archive, a SQLite file or a `postgres://` URL (default:
        /// DIR/lab.sqlite).
        #[arg(long, value_name = "URL", requires = "lab")]
        db: Option<String>,
        /// Output folder (created if missing).
        #[arg(long, default_value = "report")]
        out: PathBuf,
        /// Print report.json (lab.json with --lab) on stdout.
        #[arg(long)]
        json: bool,
    },
    /// The lab's archive of sessions, trainees, lessons and scores (docs/LESSONS.md).
    #[command(subcommand)]
    Archive(ArchiveCommand),
    /// Replay a station's journal (`scalpel-server --journal FILE`) and print the final
    /// state hash; exit status 1 if it differs from the live run's.
    Replay {
        /// The journal.
        file: PathBuf,
        /// Print {scene, ticks, state_hash, live_state_hash, identical} as JSON.
        #[arg(long)]
        json: bool,
        /// Also time each tick's stages and report the N slowest ticks and how many took
        /// over a tick of work: the simulation's own work for the session's inputs, which a
        /// station's late ticks can be compared with.
        #[arg(long, value_name = "N")]
        slowest: Option<usize>,
    },
}

/// `scalpel archive ...`.
#[derive(Subcommand)]
enum ArchiveCommand {
    /// Empty the archive and archive every journal under DIR again (the journals are the
    /// source of truth), then write the lab summary as `scalpel report --lab` does.
    Rebuild {
        /// The lab's folder of journals.
        dir: PathBuf,
        /// The archive, a SQLite file or a `postgres://` URL (default: DIR/lab.sqlite).
        #[arg(long, value_name = "URL")]
        db: Option<String>,
        /// Output folder for the summary (created if missing).
        #[arg(long, default_value = "report")]
        out: PathBuf,
        /// Print lab.json on stdout.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum LessonCommand {
    /// List the built-in lessons.
    List {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Lay a lesson on its organ and report its plan.
    Show {
        /// A built-in lesson or a lesson file.
        lesson: String,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Write a scripted trainee's blade script for a lesson (for `scalpel mock-device
    /// --script`).
    Script {
        /// A built-in lesson or a lesson file.
        lesson: String,
        /// careful, hesitant or careless.
        #[arg(long)]
        trainee: String,
        /// The script file to write (TOML).
        #[arg(long)]
        out: PathBuf,
    },
    /// Run a lesson offline with a scripted trainee or a blade script, score it and write
    /// its report (as `scalpel report` does for a station's session).
    Try {
        /// A built-in lesson or a lesson file.
        lesson: String,
        /// careful, hesitant or careless.
        #[arg(long)]
        trainee: Option<String>,
        /// A blade script (TOML or CSV) instead of a scripted trainee.
        #[arg(long)]
        script: Option<PathBuf>,
        /// Output folder (created if missing).
        #[arg(long, default_value = "report")]
        out: PathBuf,
        /// Print report.json on stdout.
        #[arg(long)]
        json: bool,
    },
}

#[derive(Subcommand)]
enum InstructCommand {
    /// Schedule a fault: device-dropout, device-latency --ms, pose-noise --sigma-mm,
    /// force-spike --newtons, force-saturation --max-n, tissue-stiffness --factor
    /// [--ramp-ms], sim-stall, sim-slowdown --factor, renderer-freeze, observer-stream-loss.
    Fault {
        /// The kind.
        kind: String,
        #[command(flatten)]
        params: instruct_cmd::FaultParams,
        /// Start at this station tick (ms since the server started; default: now).
        #[arg(long)]
        at: Option<u64>,
        /// How long (ms; 0: until cleared).
        #[arg(long, default_value_t = 0)]
        duration_ms: u32,
    },
    /// List the scheduled and active faults.
    List,
    /// Clear one fault, or all without an id.
    Clear {
        /// The fault's id (from `fault` or `list`).
        id: Option<u64>,
    },
}

#[derive(Subcommand)]
enum CertsCommand {
    /// Make a lab CA and the server's certificate (for localhost and each --host).
    Init {
        /// Folder for the files (created; must not hold a CA already).
        #[arg(long)]
        dir: PathBuf,
        /// Another name or address the server is reached by.
        #[arg(long)]
        host: Vec<String>,
    },
    /// Issue a client certificate signed by the lab CA.
    Issue {
        /// The lab's certificate folder.
        #[arg(long)]
        dir: PathBuf,
        /// What the client may do.
        #[arg(long, value_parser = ["observer", "instructor"])]
        role: String,
        /// Who it is (names the files NAME.pem and NAME.key).
        #[arg(long)]
        name: String,
    },
}

#[derive(Subcommand)]
enum SceneCommand {
    /// List the built-in scenes.
    List {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Build a scene and report its surface, interior points and build time.
    Inspect {
        #[command(flatten)]
        target: TargetArgs,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Build a scene and write its surface and interior points (VTK, PLY or OBJ, by extension).
    Export {
        #[command(flatten)]
        target: TargetArgs,
        /// Output file: .vtk (legacy, opens in ParaView), .ply or .obj.
        #[arg(long)]
        out: PathBuf,
    },
}

#[derive(Subcommand)]
enum BenchCommand {
    /// The paper's Table 1: the default scripted cut on liver, shoulder and cerebroma,
    /// surface and internal time per cut step (median, p99) against the paper's figures.
    Table1 {
        /// Threads for the simulation, as a station's `realtime.sim_threads` (1 or 2).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
        threads: u32,
        /// The physical cut instead of the default: fracture by energy (`[force]
        /// fracture_by_energy`; issue 41) on each organ's own strain-stiffening, or on
        /// `[material] stiffening` = BETA when given.
        #[arg(long, value_name = "BETA", num_args = 0..=1)]
        fracture: Option<Option<f64>>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// The physical cut's force curve on each organ beside the formula's (grey), and the
    /// incision at a quarter, half, three quarters and the end of the stroke and 2 s after
    /// (issue 41): cut-force-ORGAN.png and cut-sequence-ORGAN.png.
    CutFigures {
        /// Where the figures go.
        #[arg(long, default_value = "docs/figures")]
        out: PathBuf,
    },
    /// The default liver cut at several resolutions: cost per cut step against points.
    Scaling {
        /// Target interior point counts.
        #[arg(long, value_delimiter = ',', default_value = "1526,15000,100000")]
        points: Vec<usize>,
        /// Threads for the simulation, as a station's `realtime.sim_threads` (1 or 2).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
        threads: u32,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// A lab session on a cutting scene: many strokes one after the other (as
    /// `scalpel cut --strokes`), the cost per cut step stroke by stroke, the solver's
    /// rollbacks and divergences, and the surface at the end.
    Session {
        #[command(flatten)]
        target: TargetArgs,
        /// Strokes in the session.
        #[arg(long, default_value_t = 16)]
        strokes: usize,
        /// Seed of the strokes' places and headings.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Idle ticks of a scene (default: the liver) with and without the cutting feature:
    /// what a scene that does not cut pays for cutting (nothing), what an untouched cutting
    /// scene costs, and what a tick of the whole body costs without cutting.
    Idle {
        /// Built-in scene name, scene file (.toml) or mesh file.
        #[arg(default_value = "liver")]
        target: String,
        /// Units of a mesh file's coordinates (for a bare mesh file).
        #[arg(long, value_enum, default_value = "m")]
        units: UnitArg,
        /// Target number of interior points (overrides the scene's sampling).
        #[arg(long)]
        target_points: Option<usize>,
        /// Ticks per variant.
        #[arg(long, default_value_t = 2000)]
        ticks: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// The station's real-time loop with the release server, the mock device and frame
    /// subscribers: haptic jitter and deadline misses, pose → force at the device and
    /// pose → frame at a subscriber, with no viewers and then with several.
    Loop {
        /// Seconds per phase.
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Viewers in the second phase.
        #[arg(long, default_value_t = 4)]
        viewers: usize,
        /// Give the haptic thread this CPU to itself (the server's `realtime.haptic_cpu`).
        #[arg(long)]
        haptic_cpu: Option<usize>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Each station as a lab runs it (issue 42): the release server on each scene with a
    /// shared-memory device, the mock device looping the scene's default cut and viewers
    /// rendering every frame; simulation ticks late and their p50 / p99 / p99.9, haptic
    /// misses and jitter.
    Stations {
        /// Seconds measured per station (after 3 s of settling).
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Viewers per station.
        #[arg(long, default_value_t = 2)]
        viewers: usize,
        /// The simulation's threads (`realtime.sim_threads`: 1 or 2).
        #[arg(long, default_value_t = 2, value_parser = clap::value_parser!(u32).range(1..=2))]
        threads: u32,
        /// Built-in scenes, scene files or mesh files.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "liver,shoulder,cerebroma,../shared/meshes/liver_tumour_PPP_Tumor.obj"
        )]
        scenes: Vec<String>,
        /// Units of the mesh files' coordinates.
        #[arg(long, default_value = "cm", value_parser = ["m", "cm", "mm"])]
        mesh_units: String,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Remote observers over QUIC on loopback: frame latency, bytes per second per
    /// observer, and the haptic deadline misses they add (docs/BENCHMARKS.md).
    Net {
        /// Seconds per phase (without observers, with them).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// Observers in the second phase (30 Hz each).
        #[arg(long, default_value_t = 32)]
        observers: usize,
        /// The built-in scene.
        #[arg(long, default_value = "cerebroma")]
        scene: String,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// A station's QUIC endpoint under a flood of handshakes that never finish, from
    /// several loopback addresses, while an observer connects: how many of its attempts get
    /// in (docs/BENCHMARKS.md, "Reliability").
    Admission {
        /// The observer's connection attempts.
        #[arg(long, default_value_t = 20)]
        attempts: usize,
        /// Flooding addresses (127.0.0.2 onwards).
        #[arg(long, default_value_t = 3)]
        addresses: usize,
        /// New connection attempts per second from each flooding address.
        #[arg(long, default_value_t = 50.0)]
        rate: f64,
        /// Flood this running station instead of starting one (with --certs and --name).
        #[arg(long, requires_all = ["certs", "name"])]
        target: Option<std::net::SocketAddr>,
        /// With --target: the lab's certificate folder.
        #[arg(long)]
        certs: Option<PathBuf>,
        /// With --target: the observer certificate's name.
        #[arg(long)]
        name: Option<String>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Build every built-in scene several times and report build times.
    Scenes {
        /// Builds per scene.
        #[arg(long, default_value_t = 5)]
        runs: usize,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// The stiff and extreme cases of physics.md §9 (stiffness, ν → 0.5, huge steps,
    /// rotations, compression, tiny lattices, orphans, slivers, point loads).
    Stability {
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Error against run time: resolution sweep × solver mode on the cantilever and the
    /// uniaxial block, and the liver stroke at several resolutions (about 5 minutes in all);
    /// writes accuracy.csv and accuracy.png.
    Accuracy {
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// Fewest points across the beam.
        #[arg(long, default_value_t = 3)]
        min_across: usize,
        /// Most points across the beam.
        #[arg(long, default_value_t = 9)]
        max_across: usize,
        /// Which body: cantilever, uniaxial, cut (the liver stroke) or all.
        #[arg(long, default_value = "all")]
        case: String,
        /// The cut's resolutions, in target points (comma-separated).
        #[arg(long, value_delimiter = ',', default_values_t = bench::accuracy::CUT_POINTS)]
        cut_points: Vec<usize>,
        /// The target points of the cut's reference run.
        #[arg(long, default_value_t = bench::accuracy::CUT_REFERENCE_POINTS)]
        cut_reference: usize,
        /// Which integrator: explicit, projective, implicit, implicit-factored, implicit-two-level
        /// or all.
        #[arg(long, default_value = "all")]
        mode: String,
        /// The implicit modes' CG tolerance, relative to a tick's impulse.
        #[arg(long, default_value_t = scalpel_sim::solver::SolverConfig::default().implicit_tolerance)]
        implicit_tolerance: f64,
        /// A peers file (tools/bench/peers/run.py) whose points join the plot.
        #[arg(long)]
        peers: Option<PathBuf>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
}

/// What to build: a built-in scene name, a scene file (.toml) or a mesh file.
#[derive(Args, Clone)]
struct TargetArgs {
    /// Built-in scene name, scene file (.toml) or mesh file (.obj, .stl, .ply, .vtk).
    target: String,
    /// Units of a mesh file's coordinates (for a bare mesh file).
    #[arg(long, value_enum, default_value = "m")]
    units: UnitArg,
    /// Lattice spacing in mm (overrides the scene's sampling).
    #[arg(long, conflicts_with = "target_points")]
    spacing_mm: Option<f64>,
    /// Target number of interior points (overrides the scene's sampling).
    #[arg(long)]
    target_points: Option<usize>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum UnitArg {
    M,
    Cm,
    Mm,
}

/// A report piped into `head` ends the command quietly once the reader has what it wants,
/// as `ls | head` does, instead of a panic in `println!` (Rust starts with SIGPIPE
/// ignored). Not for `view`: its X11 connection is a socket, whose loss Xlib reports
/// itself. The other sockets we use do not raise SIGPIPE (QUIC is UDP; iceoryx2 sends with
/// MSG_NOSIGNAL).
#[allow(unsafe_code)]
fn end_quietly_when_the_reader_goes() {
    // SAFETY: restores SIGPIPE's default disposition before any other thread exists; no
    // handler runs Rust code.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

impl From<UnitArg> for LengthUnit {
    fn from(u: UnitArg) -> Self {
        match u {
            UnitArg::M => LengthUnit::M,
            UnitArg::Cm => LengthUnit::Cm,
            UnitArg::Mm => LengthUnit::Mm,
        }
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    if !matches!(cli.command, Command::View { .. }) {
        end_quietly_when_the_reader_goes();
    }
    match dispatch(cli.command) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Runs `command`; its error is reported by `main`.
fn dispatch(command: Command) -> anyhow::Result<()> {
    match command {
        Command::Demo { scene, json } => run_inspect(
            &TargetArgs {
                target: scene,
                units: UnitArg::M,
                spacing_mm: None,
                target_points: None,
            },
            json,
        ),
        Command::Scene(what) => run_scene(what),
        Command::Validate { json, only } => validate_cmd::run(json, &only),
        Command::Cut {
            target,
            script,
            strokes,
            seed,
            out,
            mesh_format,
            threads,
            json,
        } => cut_cmd::run(
            &target,
            &script_choice(script, strokes, seed),
            &out,
            &mesh_format,
            threads as usize,
            json,
        ),
        Command::Settle { target, out, json } => settle_cmd::run(&target, &out, json),
        Command::Probe { target, args } => probe_cmd::run(&target, &args),
        Command::Bench(what) => run_bench(what),
        Command::Certs(what) => run_certs(what),
        Command::Observe {
            target,
            frames,
            seconds,
            json,
            plain,
        } => observe_cmd::run(&observe_cmd::ObserveArgs {
            target: &target,
            frames,
            seconds,
            json,
            plain,
        }),
        Command::Instruct { target, json, what } => instruct_cmd::run(
            &instruct_cmd::InstructArgs {
                target: &target,
                json,
            },
            instruct_request(what),
        ),
        Command::MockDevice {
            station,
            script,
            scene,
            out,
            duration,
            looping,
            rate_hz,
            json,
        } => mock_cmd::run(&mock_cmd::MockArgs {
            station: &station,
            script: script.as_deref(),
            scene: &scene,
            out: out.as_deref(),
            options: mock_options(rate_hz, duration, looping)?,
            json,
        }),
        Command::View {
            station,
            snapshot,
            after,
            timeout,
            exit_after,
        } => match snapshot {
            Some(out) => view_cmd::snapshot(&station, &out, after, timeout),
            None => view_cmd::window(&station, exit_after),
        },
        Command::Replay {
            file,
            json,
            slowest,
        } => replay_cmd::run(&file, json, slowest),
        Command::Lesson(what) => run_lesson(what),
        Command::Report {
            journal,
            lesson,
            lab,
            db,
            out,
            json,
        } => match (lab, journal) {
            (Some(dir), _) => lab_cmd::report(&dir, db.as_deref(), &out, json),
            (None, Some(journal)) => lesson_cmd::report(&journal, lesson.as_deref(), &out, json),
            (None, None) => anyhow::bail!("give a journal or --lab DIR"),
        },
        Command::Archive(ArchiveCommand::Rebuild { dir, db, out, json }) => {
            lab_cmd::rebuild(&dir, db.as_deref(), &out, json)
        }
    }
}

/// `scalpel lesson ...`.
fn run_lesson(what: LessonCommand) -> anyhow::Result<()> {
    match what {
        LessonCommand::List { json } => lesson_cmd::list(json),
        LessonCommand::Show { lesson, json } => lesson_cmd::show(&lesson, json),
        LessonCommand::Script {
            lesson,
            trainee,
            out,
        } => lesson_cmd::script(&lesson, &trainee, &out),
        LessonCommand::Try {
            lesson,
            trainee,
            script,
            out,
            json,
        } => lesson_cmd::try_lesson(&lesson, trainee.as_deref(), script.as_deref(), &out, json),
    }
}

/// `scalpel scene ...`.
fn run_scene(what: SceneCommand) -> anyhow::Result<()> {
    match what {
        SceneCommand::List { json } => report::print_scene_list(json),
        SceneCommand::Inspect { target, json } => run_inspect(&target, json),
        SceneCommand::Export { target, out } => run_export(&target, &out),
    }
}

/// `scalpel certs ...`: prints what was made.
fn run_certs(what: CertsCommand) -> anyhow::Result<()> {
    match what {
        CertsCommand::Init { dir, host } => {
            certs_cmd::init(&dir, &host).map(|made| println!("{made}"))
        }
        CertsCommand::Issue { dir, role, name } => {
            certs_cmd::issue(&dir, &role, &name).map(|made| println!("{made}"))
        }
    }
}

/// `scalpel bench ...`.
fn run_bench(what: BenchCommand) -> anyhow::Result<()> {
    match what {
        BenchCommand::Scenes { runs, json } => bench::scenes(runs, json),
        BenchCommand::Stability { json } => bench::stability::run(json),
        BenchCommand::Table1 {
            threads,
            fracture,
            json,
        } => bench::cutting::table1(threads as usize, fracture, json),
        BenchCommand::CutFigures { out } => bench::cut_figures::cut_figures(&out),
        BenchCommand::Scaling {
            points,
            threads,
            json,
        } => bench::cutting::scaling(&points, threads as usize, json),
        BenchCommand::Idle {
            target,
            units,
            target_points,
            ticks,
            json,
        } => {
            let target = TargetArgs {
                target,
                units,
                spacing_mm: None,
                target_points,
            };
            bench::cutting::idle(&target, ticks, json)
        }
        BenchCommand::Stations {
            seconds,
            viewers,
            threads,
            scenes,
            mesh_units,
            json,
        } => bench::stations::run(&bench::stations::StationsArgs {
            seconds,
            viewers,
            threads: threads as usize,
            scenes: &scenes,
            mesh_units: &mesh_units,
            json,
        }),
        BenchCommand::Session {
            target,
            strokes,
            seed,
            json,
        } => bench::session::run(&target, strokes, seed, json),
        BenchCommand::Loop {
            seconds,
            viewers,
            haptic_cpu,
            json,
        } => bench::loop_bench::run(seconds, viewers, haptic_cpu, json),
        BenchCommand::Admission {
            attempts,
            addresses,
            rate,
            target,
            certs,
            name,
            json,
        } => {
            let target = match (target, certs, name) {
                (Some(addr), Some(certs), Some(name)) => {
                    Some(bench::admission::Target { addr, certs, name })
                }
                _ => None,
            };
            bench::admission::run(attempts, addresses, rate, target, json)
        }
        BenchCommand::Net {
            seconds,
            observers,
            scene,
            json,
        } => bench::net::run(seconds, observers, &scene, json),
        BenchCommand::Accuracy {
            out,
            min_across,
            max_across,
            case,
            cut_points,
            cut_reference,
            mode,
            implicit_tolerance,
            peers,
            json,
        } => {
            let selection = bench::accuracy::Selection {
                across: (min_across, max_across),
                case,
                mode,
                implicit_tolerance,
                peers,
                cut_points,
                cut_reference,
            };
            bench::accuracy::run(&out, &selection, json)
        }
    }
}

/// `scalpel cut`'s blade script: a file, a session of strokes, or the default stroke.
fn script_choice(
    script: Option<PathBuf>,
    strokes: Option<usize>,
    seed: u64,
) -> cut_cmd::ScriptChoice {
    match (script, strokes) {
        (Some(file), _) => cut_cmd::ScriptChoice::File(file),
        (None, Some(strokes)) => cut_cmd::ScriptChoice::Session { strokes, seed },
        (None, None) => cut_cmd::ScriptChoice::Default,
    }
}

/// The request `scalpel instruct ...` sends.
fn instruct_request(what: InstructCommand) -> instruct_cmd::Request {
    match what {
        InstructCommand::Fault {
            kind,
            params,
            at,
            duration_ms,
        } => instruct_cmd::Request::Fault {
            kind,
            params,
            at,
            duration_ms,
        },
        InstructCommand::List => instruct_cmd::Request::List,
        InstructCommand::Clear { id } => instruct_cmd::Request::Clear(id),
    }
}

/// `scalpel mock-device`'s timing, once `--rate-hz` and `--duration` are checked.
fn mock_options(
    rate_hz: f64,
    duration: Option<f64>,
    looping: bool,
) -> anyhow::Result<scalpel_client::mock_device::MockOptions> {
    if !(rate_hz.is_finite() && (10.0..=10_000.0).contains(&rate_hz)) {
        anyhow::bail!("--rate-hz must be between 10 and 10000, got {rate_hz}");
    }
    if let Some(d) = duration
        && !(d.is_finite() && d > 0.0)
    {
        anyhow::bail!("--duration must be a positive number of seconds, got {d}");
    }
    Ok(scalpel_client::mock_device::MockOptions {
        rate_hz,
        duration_s: duration,
        looping,
        ..Default::default()
    })
}

fn run_inspect(target: &TargetArgs, json: bool) -> anyhow::Result<()> {
    let spec = load::resolve(target)?;
    let timed = load::build_with_progress(&spec)?;
    report::print_scene(&timed, json)
}

fn run_export(target: &TargetArgs, out: &std::path::Path) -> anyhow::Result<()> {
    let spec = load::resolve(target)?;
    let timed = load::build_with_progress(&spec)?;
    export::write(&timed.scene, out)?;
    eprintln!(
        "wrote {} ({} surface vertices, {} triangles, {} interior points)",
        out.display(),
        timed.scene.model.surface.positions.len(),
        timed.scene.model.surface.triangles.len(),
        timed.scene.model.points.len()
    );
    Ok(())
}
