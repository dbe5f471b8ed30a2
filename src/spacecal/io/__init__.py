"""Reading and writing spacecal's files: recordings (CSV + metadata JSON), calibrations, results."""
