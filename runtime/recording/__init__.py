"""Recordings: the MCAP writer and reader, the central's recorder, replay and its
verification, the report and the plots rebuilt from a file."""
