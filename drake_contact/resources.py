"""Where the data shipped with the package lives.

The repository keeps its data in the top-level ``models/`` folder; the wheel
ships the same folder as ``drake_contact/models`` (see ``pyproject.toml``), so
both a source checkout and a non-editable install find it here.
"""

from pathlib import Path

_PACKAGE_DIR = Path(__file__).resolve().parent


def models_dir() -> Path:
    """Returns the folder holding the URDF, network weights and scenarios."""
    for candidate in (_PACKAGE_DIR / "models", _PACKAGE_DIR.parent / "models"):
        if (candidate / "arm3dof.urdf").is_file():
            return candidate
    raise FileNotFoundError(
        f"drake_contact's models/ folder was not found next to {_PACKAGE_DIR}; "
        "reinstall the package (pip install .)")


def arm_urdf_path() -> Path:
    """The 3-DOF arm's URDF."""
    return models_dir() / "arm3dof.urdf"


def scenarios_dir() -> Path:
    """The bundled scenario files, one ``NAME.yaml`` per scenario."""
    return models_dir() / "scenarios"


def bundled_scenario_names() -> list[str]:
    """Names of the bundled scenarios, sorted."""
    return sorted(p.stem for p in scenarios_dir().glob("*.yaml"))
