"""Study modules, one per paper section. Each exposes

``NAME``, ``DESCRIPTION``,
``add_arguments(parser)`` : study options for ``ecfm-uq reproduce NAME``,
``settings_from_args(args) -> dict`` : the settings recorded in ``result.json``,
``run(settings, out_dir, progress) -> dict`` : runs the study, writes figures into
``out_dir`` and returns the result (written by the caller as ``result.json``),
``summary_rows(result) -> list[dict]`` : rows ``quantity, paper, ours, holds`` for
``summary.md``.
"""

STUDY_NAMES = ("burgers", "kpp", "beam", "mc", "boundary", "geometry")
