"""Datasets of the C++ data collector (cpp_data_collector): shard reader, loading, postprocessing to npz.

Format specification: docs/data_format.md. Main entry points:
    open_dataset(dir) -> Dataset          memory-mapped shards, verify()
    load_dataset(dirs) -> LoadedRecords   every valid record as arrays
    records_to_arrays(records) -> FixedSizeArrays   the npz contract (fixed-size B-splines)
    FixedSizeArrays.load(path)            a validated npz
"""

from quad_il.data.format import (
    FORMAT_VERSION,
    CorruptDataError,
    DatasetError,
    EmptyDatasetError,
    FormatVersionError,
    NotADatasetError,
    decode_depth_codes,
    encode_depth_m,
)
from quad_il.data.postprocess import FixedSizeArrays, ResampleConfig, records_to_arrays
from quad_il.data.shards import Dataset, LoadedRecords, ShardReader, load_dataset, open_dataset

__all__ = [
    "FORMAT_VERSION",
    "CorruptDataError",
    "Dataset",
    "DatasetError",
    "EmptyDatasetError",
    "FixedSizeArrays",
    "FormatVersionError",
    "LoadedRecords",
    "NotADatasetError",
    "ResampleConfig",
    "ShardReader",
    "decode_depth_codes",
    "encode_depth_m",
    "load_dataset",
    "open_dataset",
    "records_to_arrays",
]
