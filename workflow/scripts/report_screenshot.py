"""Check that a report renders: headless Chromium screenshot and how much of it is drawn.

Run: python workflow/scripts/report_screenshot.py results/report.html results/report.png
Exit status 1 when the page is (nearly) blank or Chromium is missing.
"""
import sys

from condor.report.screenshot import screenshot, screenshot_coverage

html_path = sys.argv[1] if len(sys.argv) > 1 else "results/report.html"
png_path = sys.argv[2] if len(sys.argv) > 2 else html_path.removesuffix(".html") + ".png"
try:
    coverage = screenshot_coverage(screenshot(html_path, png_path))
except (ValueError, RuntimeError) as err:
    sys.exit(f"cannot render {html_path}: {err}")
print(f"{png_path}: {coverage}")
if coverage["rows_with_ink"] < 0.3 or coverage["ink_fraction"] < 0.02:
    sys.exit(f"{html_path} renders (nearly) blank: {coverage}")
