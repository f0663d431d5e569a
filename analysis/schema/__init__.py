"""The results table: one row per run (``columns.py``), the files it is stored in (``files.py``), and the
run-folder contract a training run's row is read by (``run_folder.py``).

The names below are the package's public surface (``from analysis.schema import X``).
"""

from analysis.schema.columns import (CLOSEST_TO_GT, GROUND_TRUTH, LOWER_IS_BETTER, METRICS, ROW_KINDS, SHARED_COLUMNS,
                                     Column, Row, column, column_by_name, columns, config_label, families,
                                     family_columns, lenient_row, make_row, numeric_columns, validate_row)
from analysis.schema.files import load_results, rows_to_csv, save_results
from analysis.schema.run_folder import row_from_run_dir
from handx_jax.infra.errors import DataError

__all__ = ["CLOSEST_TO_GT", "GROUND_TRUTH", "LOWER_IS_BETTER", "METRICS", "ROW_KINDS", "SHARED_COLUMNS", "Column", "Row",
           "column", "column_by_name", "columns", "config_label", "families", "family_columns", "lenient_row",
           "make_row", "numeric_columns", "validate_row", "load_results", "rows_to_csv", "save_results",
           "row_from_run_dir", "DataError"]
