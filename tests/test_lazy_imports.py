"""A run that records MCAP alone (the suites) or nothing does not import the log readers'
pandas nor Rerun at its start, nor does a sweep job's progress line; the names stay where they
were."""

import subprocess
import sys


def test_a_run_process_loads_neither_pandas_nor_rerun_until_asked(tmp_path):
    code = ("import sys, tamedpuma.app.sweep, tamedpuma.runlog, tamedpuma.recording as r\n"
            f"recs = r.make_recorders(['mcap'], {str(tmp_path)!r})\n"
            "assert type(recs[0]).__name__ == 'McapRecorder'\n"
            "from omegaconf import OmegaConf\n"
            "from tamedpuma.app.callbacks import progress_line\n"
            f"d = {str(tmp_path)!r}\n"
            "progress_line(OmegaConf.create({'hydra': {'sweep': {'dir': d}, "
            "'runtime': {'output_dir': d + '/run'}}}), None)\n"
            "print(sorted(m for m in ('pandas', 'rerun', 'pyarrow') if m in sys.modules))\n"
            "r.read_mcap\n"
            "print('pandas' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[:2] == ["[]", "True"]


def test_the_lazy_names_are_the_modules_own():
    from tamedpuma import recording
    from tamedpuma.recording import reader, rerun_writer

    assert recording.read_mcap is reader.read_mcap and recording.RunLog is reader.RunLog
    assert recording.RerunRecorder is rerun_writer.RerunRecorder
    assert recording.RECORDERS == {"mcap": (recording.McapRecorder, "episode.mcap"),
                                   "rerun": (rerun_writer.RerunRecorder, "episode.rrd")}
    assert set(recording.__all__) <= set(dir(recording)) | set(recording._LAZY) | {"RECORDERS"}
