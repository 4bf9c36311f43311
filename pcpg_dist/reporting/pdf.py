"""A report printed to PDF by a headless Chromium (the distribution's package); folded sections
stay folded."""

from __future__ import annotations

from pathlib import Path


def chromium() -> str | None:
    """The Chromium executable (the distribution's package), or None."""
    import shutil

    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


def export_pdf(html_path: Path, pdf_path: Path | None = None, timeout: float = 120.0) -> Path:
    """Print the report to PDF with a headless Chromium; folded sections stay folded."""
    import os
    import subprocess

    from pcpg_dist.common.errors import ServiceError

    html_path = Path(html_path).resolve()
    pdf_path = Path(pdf_path or html_path.with_suffix(".pdf")).resolve()
    exe = chromium()
    if exe is None:
        raise ServiceError(
            "--pdf needs Chromium (apt-get install -y chromium); or open report.html in a "
            "browser and print it"
        )
    cmd = [
        exe,
        "--headless",
        "--disable-gpu",
        "--no-pdf-header-footer",
        f"--print-to-pdf={pdf_path}",
        html_path.as_uri(),
    ]
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        cmd.insert(1, "--no-sandbox")  # Chromium refuses to run as root with its sandbox
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as e:
        raise ServiceError(f"--pdf: Chromium failed ({e})") from None
    if not pdf_path.is_file() or pdf_path.read_bytes()[:5] != b"%PDF-":
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1][:300]
        raise ServiceError(f"--pdf: Chromium wrote no PDF (exit {done.returncode}: {tail})")
    return pdf_path
