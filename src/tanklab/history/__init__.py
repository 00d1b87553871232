"""History: the value types the historian stores and HistoryRead serves (pure kernel).

``model`` holds the records (a tag's sample, an event); the historian tier's stores and the
OPC UA Part 11 / Part 13 services speak these types and nothing else.
"""
