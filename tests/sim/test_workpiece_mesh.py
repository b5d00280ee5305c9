"""The workpiece's surfaces for viewers (droid.sim.workpiece_mesh, issue 29): the sensors' own model, sampled."""
from __future__ import annotations

import numpy as np

from droid.sim.seam3d import TACK_WIDTH_MM
from droid.sim.workpiece import bundled_workpieces, load_workpiece
from droid.sim.workpiece_mesh import VIEW_STEP_MM, section_s, workpiece_mesh


def sections(m):
    return np.asarray(m["points"], float).reshape(m["sections"], m["per_section"], 3)


def test_every_bundled_workpiece_meshes_small():
    for name in bundled_workpieces():
        m = workpiece_mesh(load_workpiece(name))
        assert m["name"] == name and m["per_section"] == 6
        assert len(m["points"]) == 18 * m["sections"] == 18 * len(m["gap"]) == 18 * len(m["tack"])
        assert 100 < m["sections"] < 400  # a few tens of kB of JSON


def test_sections_follow_the_seam_and_its_rolled_surfaces():
    """The foot is the model's seam point; the surfaces run across along the model's rolled lateral,
    the step (and no more) above the foot along its rolled normal."""
    for name in ("cad_curve", "helix_r300", "step_input"):
        wp = load_workpiece(name)
        seam = wp.seam
        m = workpiece_mesh(wp)
        P = sections(m)
        ss = section_s(seam)
        assert np.all(np.diff(ss) <= VIEW_STEP_MM + 1e-9)
        for i in range(0, len(ss), 7):
            p, _, n, lat = seam.point_frame(float(ss[i]))
            up = seam.upper_sign * lat
            assert np.allclose(P[i, 1], p, atol=0.01)
            assert np.allclose(P[i, 5] - P[i, 1], float(seam.step_at(ss[i])) * n + seam.width_mm * up, atol=0.02)
            assert np.allclose(P[i, 0] - P[i, 1], -seam.width_mm * up, atol=0.02)
    # the rolled piece really rolls: the upper surface's lateral leaves the plan at 20 deg
    wp = load_workpiece("cad_curve")
    P, ss = sections(workpiece_mesh(wp)), section_s(wp.seam)
    i = int(np.argmin(np.abs(ss - 400.0)))
    across = P[i, 5] - P[i, 4]
    tilt = np.degrees(np.arcsin(abs(across[2]) / np.linalg.norm(across)))
    assert 15.0 < tilt < 25.0, tilt


def test_gaps_and_tacks_are_in_the_mesh():
    wp = load_workpiece("gaps_tacks")
    m = workpiece_mesh(wp)
    P, ss = sections(m), section_s(wp.seam)
    gap = np.asarray(m["gap"], bool)
    tack = np.asarray(m["tack"], bool)
    for a, n in wp.gaps:  # no step inside a gap, one just outside it
        inside = (ss > a) & (ss < a + n)
        assert inside.any() and gap[inside].all()
        assert np.allclose(P[inside, 2], P[inside, 1], atol=0.01)
    for a, n, h in wp.tacks:
        inside = (ss > a) & (ss < a + n)
        assert inside.any() and tack[inside].all()
        height = np.linalg.norm(P[inside, 2] - P[inside, 1], axis=1)
        assert np.allclose(height, wp.seam.step_at(ss[inside]) + h, atol=0.01)
        assert np.allclose(np.linalg.norm(P[inside, 3] - P[inside, 2], axis=1), TACK_WIDTH_MM, atol=0.01)
    assert not gap[(ss > 50) & (ss < 150)].any() and not tack[(ss > 50) & (ss < 150)].any()
