//! `monitor --frames-every`: the twin that follows a robot is drawn where it stands.

use twinbots_ops::monitor::{Monitor, MonitorOptions, Report};
use twinbots_render::View;

/// The UR5e twin standing at `q`, as the monitor builds it from a robot's first report.
fn monitor_at(q: [f64; 6]) -> Monitor {
    let first = Report { time: 1.0, q, qd: [0.0; 6], command: [0.0; 6], effort: [0.0; 6] };
    Monitor::new(MonitorOptions::default(), &first).unwrap()
}

#[test]
fn the_monitors_twin_is_rendered_where_the_robot_stands() {
    let (w, h) = (160, 120);
    let Some(mut renderer) = crate::renderer("the_monitors_twin_is_rendered_where_the_robot_stands", w, h) else {
        return;
    };
    let entry = twinbots_run::registry::find("ur5e").unwrap();
    renderer.set_view(View::framed(&entry.framing, "iso").unwrap());
    let mut frame = |q: [f64; 6]| {
        let mut monitor = monitor_at(q);
        let (world, arena) = monitor.twin_scene();
        renderer.sync(world, arena);
        renderer.render().unwrap()
    };
    let home = ur5e::kinematics::HOME.map(|v| v as f64);
    let mut turned = home;
    turned[0] += 1.2;
    let (a, b) = (frame(home), frame(turned));
    assert_eq!(a.len(), (w * h * 3) as usize);
    // The arm stands out from the empty stand's background, and moves when the pan turns.
    let background = [a[0], a[1], a[2]];
    let arm = a.chunks(3).filter(|p| p.iter().zip(background).any(|(c, b)| c.abs_diff(b) > 30)).count();
    assert!(arm > 200, "the arm covers {arm} pixels of {}", w * h);
    let moved =
        a.chunks(3).zip(b.chunks(3)).filter(|(p, q)| p.iter().zip(q.iter()).any(|(x, y)| x.abs_diff(*y) > 30)).count();
    assert!(moved > 100, "turning the pan by 1.2 rad changed {moved} pixels");
}
