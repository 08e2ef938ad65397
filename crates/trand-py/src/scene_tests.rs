//! The scene on a generated tiny sequence: save/load round trips, updates, argument errors.

use std::sync::atomic::AtomicBool;

use trand_io::{ScratchDir, Sequence, ViewCount, select_train_views};
use trand_pipeline::associate::Identity;
use trand_pipeline::{PipelineError, ReconstructOptions};

use super::{Scene, SceneError};

fn tiny(dir: &ScratchDir) -> Sequence {
    let out = dir.path().join("tiny");
    let mut c = trand_synth::SynthConfig::new(trand_synth::Preset::Tiny, 3, &out);
    c.progress = trand_synth::Progress::Hidden;
    trand_synth::generate(&c).unwrap();
    trand_io::read_sequence(&out).unwrap()
}

fn quick() -> ReconstructOptions {
    let mut o = ReconstructOptions::default();
    o.train.iterations = 30;
    o
}

fn reconstruct(seq: &Sequence, opts: &ReconstructOptions, cancel: bool) -> super::Result<Scene> {
    let views = select_train_views(&seq.train_t0, ViewCount::Six);
    Scene::reconstruct(views, opts, &mut |_| {}, &AtomicBool::new(cancel))
}

fn argument_of(r: super::Result<Scene>) -> String {
    match r {
        Err(SceneError::Argument { arg, .. }) => arg,
        other => panic!(
            "expected an argument error, got {:?}",
            other.map(|s| s.state)
        ),
    }
}

#[test]
fn a_saved_scene_loads_back_and_updates_alike() {
    let dir = ScratchDir::new("py-scene").unwrap();
    let seq = tiny(&dir);
    let scene = reconstruct(&seq, &quick(), false).unwrap();
    let run = dir.path().join("run0");
    scene.save(&run).unwrap();
    let back = Scene::load(&run).unwrap();
    assert_eq!(back.surfels, scene.surfels);
    assert_eq!(
        (back.channels.clone(), back.clamp),
        (scene.channels.clone(), scene.clamp)
    );
    let cam = seq.test_t0[0].camera;
    assert_eq!(
        back.render(&cam, None).unwrap().depth,
        scene.render(&cam, None).unwrap().depth
    );
    let new = seq.train_t1.iter().find(|v| v.frame == 0).unwrap();
    let never = AtomicBool::new(false);
    let a = scene
        .update(new, None, Identity::Auto, &mut |_, _, _| {}, &never)
        .unwrap();
    let b = back
        .update(new, None, Identity::Auto, &mut |_, _, _| {}, &never)
        .unwrap();
    assert_eq!(a.surfels, b.surfels);
    assert_eq!(Some(a.removed.clone()), seq.removed_ids);
    assert_eq!(back.surfels, scene.surfels, "the t=0 scene is unchanged");
    assert!(!a.object_ids().iter().any(|id| a.removed.contains(id)));
    // A t = 1 scene is not updated again, and unknown ids are named.
    assert_eq!(
        argument_of(a.update(new, None, Identity::Auto, &mut |_, _, _| {}, &never)),
        "self"
    );
    assert_eq!(
        argument_of(scene.update(
            new,
            Some(vec![9]),
            Identity::Auto,
            &mut |_, _, _| {},
            &never
        )),
        "removed"
    );
    assert!(matches!(
        scene.points(Some(9)),
        Err(SceneError::Argument { arg, .. }) if arg == "object_id"
    ));
    assert!(matches!(
        scene.save(&run),
        Err(SceneError::Io(trand_io::IoError::Output { .. }))
    ));
}

#[test]
fn masks_without_objects_are_refused_and_a_set_cancel_flag_interrupts() {
    let dir = ScratchDir::new("py-scene-args").unwrap();
    let seq = tiny(&dir);
    assert!(matches!(
        reconstruct(&seq, &quick(), true),
        Err(SceneError::Pipeline(PipelineError::Interrupted(_)))
    ));
    let mut empty = seq.clone();
    for v in &mut empty.train_t0 {
        if let Some(m) = v.instance.as_mut() {
            m.data.fill(0);
        }
    }
    assert_eq!(argument_of(reconstruct(&empty, &quick(), false)), "masks");
}
