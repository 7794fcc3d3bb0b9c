import pytest
from scipy.stats import chi2

from semslam.chi2 import chi2_quantile


@pytest.mark.parametrize("dof", [1, 2, 3, 4, 8, 12])
@pytest.mark.parametrize("probability", [0.5, 0.95, 0.99, 0.999, 0.99999])
def test_chi2_quantile_is_scipy_stats_ppf(probability: float, dof: int) -> None:
    assert chi2_quantile(probability, dof) == pytest.approx(chi2.ppf(probability, dof), rel=1e-12)


def test_known_values() -> None:
    assert chi2_quantile(0.95, 3) == pytest.approx(7.814727903251178)
    assert chi2_quantile(0.999, 3) == pytest.approx(16.266, abs=1e-3)


@pytest.mark.parametrize("probability", [0.0, 1.0, -0.1, 1.5])
def test_probability_outside_the_open_interval_is_refused(probability: float) -> None:
    with pytest.raises(ValueError, match="probability must be in"):
        chi2_quantile(probability, 3)


def test_the_mapper_and_localizer_do_not_import_scipy_stats() -> None:
    import subprocess
    import sys

    code = (
        "import sys, semslam.cli, semslam.mapping.mapper, semslam.localization.localizer;"
        "print('scipy.stats' in sys.modules, 'scipy.optimize' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
