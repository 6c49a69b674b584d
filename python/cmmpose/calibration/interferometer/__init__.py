"""Error maps from laser-interferometer runs (thesis section 3.3).

The thesis measured its maps with an HP/Renishaw laser interferometer: the axis
is homed, the error terms are set to zero there, the carriage steps along the
axis and at every step the scale position and the interferometer reading are
recorded (thesis lines 703, 754-756); linear readings are corrected for the
refractive index of air from a weather station (lines 758-772); angular optics
replace the linear ones for the angles (line 774); roll is not measured and is
stored as 0 (line 793); the table is the average of three or five readings
(line 822). This package does the same from raw runs, one module a step:

1. :mod:`.air`: the refractive index of air of section 3.3
   (:func:`refractivity`, :func:`refractive_index`), the wavelength correction
   of a reading (:func:`correction_factor`, :func:`correct_reading`) and its GUM
   uncertainty (:func:`refractive_index_budget`, :func:`refractivity_uncertainty`);
2. :mod:`.runfile`: the raw run file (:class:`InterferometerRun`,
   :func:`read_run`, :func:`write_run`; docs/interferometer.md);
3. :mod:`.processing`: processing of one run into one map component
   (:func:`process_run` -> :class:`ProcessedRun`): air correction (linear
   optics only), material temperature kept or normalised to 20 C, zero at
   home, repeats and directions averaged, reversal and repeatability reported;
4. :mod:`.maps`: assembly of the 18 carriage components and 3 squareness
   values into an :class:`~cmmpose.ErrorMap` (:func:`map_from_runs`,
   :func:`build_map`), and comparison of two maps (:func:`compare_maps`,
   :func:`plot_map_difference`).

Units: positions and linear readings mm, straightness readings and map
deltas um, angles arc-second, temperatures degrees C, pressure mmHg,
humidity % RH, refractivity N = (n - 1) * 1e6 (ppm). Line numbers are those
of the thesis's plain text (data/SOURCES.md).
"""

from ...errors import InterferometerRunError, InterferometerWarning
from .air import (
    HENE_VACUUM_WAVELENGTH_NM,
    READING_BASES,
    STANDARD_AIR,
    THESIS_AIR_UNCERTAINTY,
    THESIS_SENSITIVITIES_PPM,
    THESIS_TOTAL_UNCERTAINTY_PPM,
    correct_reading,
    correction_factor,
    refractive_index,
    refractive_index_budget,
    refractivity,
    refractivity_partials,
    refractivity_uncertainty,
    wavelength_in_air_nm,
)
from .maps import MapBuild, MapComparison, build_map, compare_maps, map_from_runs, plot_map_difference
from .processing import ProcessedRun, positional_deviations, process_run
from .runfile import OPTICS, InterferometerRun, read_run, run_columns, write_run

__all__ = [
    "InterferometerRunError",
    "InterferometerWarning",
    "STANDARD_AIR",
    "HENE_VACUUM_WAVELENGTH_NM",
    "THESIS_SENSITIVITIES_PPM",
    "THESIS_AIR_UNCERTAINTY",
    "THESIS_TOTAL_UNCERTAINTY_PPM",
    "OPTICS",
    "READING_BASES",
    "refractivity",
    "refractive_index",
    "refractivity_partials",
    "wavelength_in_air_nm",
    "correction_factor",
    "correct_reading",
    "refractive_index_budget",
    "refractivity_uncertainty",
    "InterferometerRun",
    "read_run",
    "write_run",
    "run_columns",
    "ProcessedRun",
    "process_run",
    "positional_deviations",
    "MapBuild",
    "build_map",
    "map_from_runs",
    "MapComparison",
    "compare_maps",
    "plot_map_difference",
]
