//! Where a monitored robot's reports come from: its controller's RTDE outputs, or a ROS 2
//! driver's joint states overheard on DDS ([`super::ros2`]).

use std::time::Duration;

use twinbots_rtde::{DataPackage, RtdeClient};

use super::Report;

/// The robot's report stream (one per run: its size does not matter).
#[allow(clippy::large_enum_variant)]
pub enum Source {
    Rtde(RtdeClient),
    #[cfg(feature = "ros2")]
    Ros2(super::ros2::Ros2Source),
}

impl Source {
    /// The controller at `rtde` (`HOST[:PORT]`), else a ROS 2 driver on DDS domain `domain`
    /// (default `ROS_DOMAIN_ID`, else 0) whose joint states name `joints` (the arm's six, in
    /// the controller's order); each waits `patience` for a first report.
    pub fn open(
        rtde: Option<&str>,
        domain: Option<&str>,
        joints: &[String],
        patience: Duration,
    ) -> anyhow::Result<Self> {
        if let Some(address) = rtde {
            let mut client = RtdeClient::connect(address, patience)?;
            client.setup_outputs(
                &["timestamp", "actual_q", "actual_qd", "target_qd", "target_moment"],
                twinbots_rtde::MAX_FREQUENCY,
            )?;
            client.start()?;
            return Ok(Source::Rtde(client));
        }
        Self::open_ros2(domain, joints, patience)
    }

    #[cfg(feature = "ros2")]
    fn open_ros2(domain: Option<&str>, joints: &[String], patience: Duration) -> anyhow::Result<Self> {
        use twinbots_ros2::node::{domain_from_env, parse_domain};
        let domain = match domain {
            Some(d) => parse_domain(d)?,
            None => domain_from_env()?,
        };
        let name = format!("twinbots_monitor_{}", std::process::id());
        Ok(Source::Ros2(super::ros2::Ros2Source::open(domain, &name, joints, patience)?))
    }

    #[cfg(not(feature = "ros2"))]
    fn open_ros2(_: Option<&str>, _: &[String], _: Duration) -> anyhow::Result<Self> {
        anyhow::bail!("this twinbots was built without the ros2 feature: --ros2 needs it (docs/ros2.md)")
    }

    /// The source as people read it.
    pub fn label(rtde: Option<&str>) -> String {
        match rtde {
            Some(a) => format!("RTDE at {a}"),
            None => "ROS 2 (/joint_states)".into(),
        }
    }

    /// The next report; `Err(reason)` inside when the robot went (the run ends, what was
    /// followed is written); the outer error for a report that is not one.
    pub fn receive(&mut self) -> anyhow::Result<Result<Report, String>> {
        match self {
            Source::Rtde(client) => match client.receive() {
                Ok(p) => Ok(Ok(report(&p)?)),
                Err(e) => Ok(Err(e.to_string())),
            },
            #[cfg(feature = "ros2")]
            Source::Ros2(source) => {
                use super::ros2::Next;
                loop {
                    match source.next()? {
                        Next::Report(r) => return Ok(Ok(r)),
                        Next::Silent(wait) => {
                            return Ok(Err(format!("no joint state for {:.1} s", wait.as_secs_f64())));
                        }
                        Next::Note(note) => println!("monitor: {note}"),
                    }
                }
            }
        }
    }
}

/// An RTDE data package as a report: every value present and finite.
fn report(p: &DataPackage) -> anyhow::Result<Report> {
    let six = |name: &str| -> anyhow::Result<[f64; 6]> {
        let v = p.vector6(name).ok_or_else(|| anyhow::anyhow!("the controller's report has no {name}"))?;
        anyhow::ensure!(v.iter().all(|x| x.is_finite()), "the controller reported {name} = {v:?}");
        Ok(v)
    };
    Ok(Report {
        time: p.double("timestamp").ok_or_else(|| anyhow::anyhow!("the controller's report has no timestamp"))?,
        q: six("actual_q")?,
        qd: six("actual_qd")?,
        command: six("target_qd")?,
        effort: six("target_moment")?,
    })
}
