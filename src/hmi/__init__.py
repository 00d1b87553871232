"""The browser HMI (issue 17): a SCADA screen over the tiers' and the historian's OPC UA servers.

:mod:`hmi.mimic` draws a site's P&ID from its config (pure).
"""
