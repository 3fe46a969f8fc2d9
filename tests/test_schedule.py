from ctp_core.config import AlignConfig, schedule


def test_weights_grow_log_spaced_and_steps_add_up():
    cfg = AlignConfig.from_preset("default", optim={"steps": 100, "phases": 3},
                                  loss={"lambda_icp": (1.0, 100.0), "lambda_pen": (10.0, 1000.0)})
    plan = schedule.phases(cfg, allow_penetration=False)
    assert [p.lambda_icp for p in plan] == [1.0, 10.0, 100.0]
    assert [round(p.lambda_pen) for p in plan] == [10, 100, 1000]
    assert sum(p.steps for p in plan) == 100
    assert plan[0].look_at_beta == 0.0 and plan[-1].look_at_beta == cfg.camera.look_at_beta_last
    assert plan[0].zoom == 1.0 and abs(plan[-1].zoom - cfg.camera.zoom_last) < 1e-9


def test_penetration_allowed_zeroes_its_weight_and_schedule_off_fixes_cameras():
    cfg = AlignConfig.from_preset("default", camera={"schedule": False})
    plan = schedule.phases(cfg, allow_penetration=True)
    assert all(p.lambda_pen == 0 for p in plan)
    assert all(p.look_at_beta == 0 and p.zoom == 1 for p in plan)
