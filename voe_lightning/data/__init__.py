"""The generated data and its store: a record to bytes and back (``store_codec``), shards and
their files (``store_shards``), the plan of which seeds go where (``store_plan``), reading a
store (``store``), generating one (``generate``, ``generate_manifest``, ``worker_pool``) and the
contact sheets that show it (``contact_sheet``)."""
