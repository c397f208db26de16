"""Readers of recorded-data formats (UTIL CSVs and surveys, rcv_twr sequences); see harness/flight/loaders.py."""
