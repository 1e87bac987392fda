"""studyctl.devices"""
