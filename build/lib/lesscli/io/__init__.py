"""File formats: scan sets, label volumes, predictions, records, atomic writes."""
