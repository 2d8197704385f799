#!/usr/bin/env python3
"""Uploads a folder to an S3-compatible server with boto3 (the remote-store tests' uploader):

    s3_upload.py ENDPOINT_URL BUCKET FOLDER PREFIX

creates BUCKET if it does not exist and puts every file under FOLDER at PREFIX/RELATIVE_PATH.
Credentials and region come from the environment (AWS_ACCESS_KEY_ID, ...), as for any boto3
client.
"""

import os
import sys

import boto3


def main():
    if len(sys.argv) != 5:
        sys.exit("usage: s3_upload.py ENDPOINT_URL BUCKET FOLDER PREFIX")
    endpoint, bucket, folder, prefix = sys.argv[1:]
    s3 = boto3.client("s3", endpoint_url=endpoint)
    existing = [b["Name"] for b in s3.list_buckets().get("Buckets", [])]
    if bucket not in existing:
        s3.create_bucket(Bucket=bucket)
    count = 0
    for dirpath, _, files in os.walk(folder):
        for name in files:
            full = os.path.join(dirpath, name)
            rel = os.path.relpath(full, folder).replace(os.sep, "/")
            key = f"{prefix.strip('/')}/{rel}" if prefix.strip("/") else rel
            s3.upload_file(full, bucket, key)
            count += 1
    print(f"uploaded {count}", flush=True)


if __name__ == "__main__":
    main()
