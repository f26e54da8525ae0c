"""The SLAM back-end: measurement models, association weights, mixtures and the iSAM2 driver."""
