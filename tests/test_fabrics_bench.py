"""The benchmark command's plumbing (not its timings): obstacles, figures, the Markdown section."""

from __future__ import annotations

import numpy as np

from tamedpuma.app.bench_fabrics import (
    markdown_section,
    random_obstacles,
    time_counts,
    update_markdown,
)


def test_random_obstacles_keep_clear_of_the_arm():
    rng = np.random.default_rng(0)
    spheres = np.array([[0.0, 0.0, 0.5], [0.3, 0.0, 0.8]])
    centers, radii, vel = random_obstacles(rng, 50, spheres, np.array([0.09, 0.07]), 0.15)
    gap = np.linalg.norm(centers[:, None] - spheres[None], axis=-1) - [0.09, 0.07] - radii[:, None]
    assert centers.shape == (50, 3) and np.all(gap > 0.15) and np.all(vel == 0)


def test_time_counts_and_markdown_keep_other_sections(tmp_path):
    rows, build_ms, kin_ms = time_counts(counts=(0, 3), calls=5)
    assert [r["n_obstacles"] for r in rows] == [0, 3]
    assert all(r["p10_ms"] <= r["median_ms"] <= r["p90_ms"] for r in rows)
    assert np.isfinite(build_ms) and np.isfinite(kin_ms)
    report = {"date": "today", "results": rows, "build_ms": build_ms,
              "kinematics_median_ms": kin_ms,
              "machine": {"cpu_model": "cpu", "cores": 2, "python": "3", "numpy": "2",
                          "blas": "blas"}}
    path = tmp_path / "BENCHMARKS.md"
    path.write_text("# Benchmarks\n\n## PUMA training\nkeep me\n\n## Fabrics\nold\n\n## Z\nz\n")
    update_markdown(path, markdown_section(report))
    text = path.read_text()
    assert "keep me" in text and "## Z\nz" in text and "old" not in text
    assert text.count("## Fabrics") == 1 and "| 3 |" in text
    fresh = tmp_path / "NEW.md"
    update_markdown(fresh, markdown_section(report))
    assert fresh.read_text().startswith("# Benchmarks\n\n## Fabrics")
