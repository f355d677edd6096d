"""hsa_identification: excitation, rest-strain calibration, system identification, model
verification, workspace map."""
