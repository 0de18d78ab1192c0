# Surrogate training and evaluation (filled in by the surrogate stage).
