"""Relay: validates messages on one key and republishes them on another."""
